//! `NAME.report.html`: one self-contained page per job that a person opens from a file browser, a phone or
//! a link in a monitoring tool — the pictures first, then the gates with their values and bounds, the
//! stages, the caps, a scan's views and residuals, the FEA and the provenance; for a quarantined job, why.
//!
//! Made from the bundle directory alone ([`Bundle::load`]), so `scanstation report DIR` makes the same bytes
//! again. Safe to open: every text from an input or a client is escaped; the pictures are embedded as
//! `data:` URIs, so the page loads nothing from anywhere; it ships no script; its Content-Security-Policy
//! (`default-src 'none'`, images from `data:` only, its one style block by hash) forbids the rest.

mod html;
mod page;

use std::path::{Path, PathBuf};

use base64::Engine as _;
use serde_json::Value;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::{FileDigest, write_atomic};
pub use html::esc;

/// Largest JSON record of a bundle the page reads (a fusion report of many views is far below).
const MAX_RECORD_BYTES: u64 = 64 << 20;

/// Largest picture the page embeds; a larger (or unreadable) PNG is named on the page instead: the page's
/// policy loads images from `data:` URIs only, so a link to the file would show nothing.
const MAX_EMBED_BYTES: u64 = 4 << 20;

/// The page beside the STEP file `NAME.step` that `convert --pictures` writes: `NAME.report.html`.
pub fn convert_page_path(step: &Path) -> PathBuf {
    step.with_extension("report.html")
}

/// What the page is made from: a job's bundle (outbox or quarantine) or `convert`'s output directory. Its
/// manifest is not read: the page lists the files it finds, hashed (the manifest is written after it).
#[derive(Clone, Debug, Default)]
pub struct Bundle {
    /// The directory.
    pub dir: PathBuf,
    /// The page's file stem (`<stem>.report.html`).
    pub stem: String,
    /// The page's title: the input's name as given.
    pub title: String,
    /// `<stem>.report.json` (the daemon's, with the conversion report as `convert`) or a conversion report.
    pub report: Option<Value>,
    /// `error.json` of a quarantined job.
    pub error: Option<Value>,
    /// A scan's `<stem>.fusion.json`.
    pub fusion: Option<Value>,
    /// The FEA's `<stem>.fea.json`.
    pub fea: Option<Value>,
    /// Pictures by kind (`deviation`, …, `thumbnail`).
    pub pictures: Vec<(String, PathBuf)>,
    /// Every other top-level file (for the provenance table), sorted by name.
    pub files: Vec<PathBuf>,
}

impl Bundle {
    /// Read a bundle directory's records and list its pictures and files.
    ///
    /// # Errors
    /// `input.not-found` when `dir` is not a directory; `input.bad-header` when a record is not JSON;
    /// `input.no-geometry` when it holds no record of a job (no report, no error).
    pub fn load(dir: &Path) -> Result<Bundle> {
        let rd = std::fs::read_dir(dir)
            .map_err(|e| Error::new(ErrorCode::InputNotFound, format!("not a bundle directory: {e}")).in_file(dir))?;
        let mut names: Vec<String> = rd
            .flatten()
            .filter(|e| e.path().is_file())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| !n.starts_with('.'))
            .collect();
        names.sort();
        let mut b = Bundle { dir: dir.to_path_buf(), ..Default::default() };
        for n in &names {
            let p = dir.join(n);
            if let Some(stem) = n.strip_suffix(".report.json") {
                b.stem = stem.to_string();
                b.report = Some(read_json(&p)?);
            } else if n == "error.json" {
                b.error = Some(read_json(&p)?);
            } else if n.ends_with(".fusion.json") {
                b.fusion = Some(read_json(&p)?);
            } else if n.ends_with(".fea.json") {
                b.fea = Some(read_json(&p)?);
            }
            if let Some(kind) = picture_kind(n) {
                b.pictures.push((kind.to_string(), p.clone()));
            }
            if n != "manifest.json" && !n.ends_with(".report.html") {
                b.files.push(p);
            }
        }
        if b.report.is_none() && b.error.is_none() {
            return Err(Error::new(
                ErrorCode::InputNoGeometry,
                "no NAME.report.json or error.json: not a job's bundle",
            )
            .in_file(dir));
        }
        if b.stem.is_empty() {
            b.stem =
                names.iter().find_map(|n| n.strip_suffix(".report.html")).map(str::to_string).unwrap_or_else(|| {
                    dir.file_name().map(|d| d.to_string_lossy().into_owned()).unwrap_or_else(|| "job".into())
                });
        }
        b.title = title(&b);
        Ok(b)
    }

    /// Where the page goes: `<dir>/<stem>.report.html`.
    pub fn page_path(&self) -> PathBuf {
        self.dir.join(format!("{}.report.html", self.stem))
    }
}

/// The picture kind of a file name `….KIND.png` (or `stress.png`).
fn picture_kind(name: &str) -> Option<&'static str> {
    let base = name.strip_suffix(".png")?;
    let kind = base.rsplit('.').next()?;
    page::PICTURES.iter().map(|(k, _)| *k).chain(["thumbnail"]).find(|k| *k == kind)
}

/// The input's name as given (from the report or the error record), else the stem.
fn title(b: &Bundle) -> String {
    let from = |v: &Option<Value>| {
        v.as_ref()
            .and_then(|r| r.get("input").or_else(|| r.get("input_file")))
            .and_then(Value::as_str)
            .map(|s| Path::new(s).file_name().map_or_else(|| s.to_string(), |n| n.to_string_lossy().into_owned()))
    };
    from(&b.report).or_else(|| from(&b.error)).unwrap_or_else(|| b.stem.clone())
}

fn read_json(p: &Path) -> Result<Value> {
    let len = std::fs::metadata(p).map(|m| m.len()).unwrap_or(0);
    if len > MAX_RECORD_BYTES {
        return Err(Error::new(ErrorCode::InputTooLarge, format!("a record of {len} bytes")).in_file(p));
    }
    let text = std::fs::read(p).map_err(|e| Error::new(ErrorCode::InputIo, e.to_string()).in_file(p))?;
    serde_json::from_slice(&text)
        .map_err(|e| Error::new(ErrorCode::InputBadHeader, format!("not JSON: {e}")).in_file(p))
}

/// The `src` of a picture: its bytes as a `data:` URI; `None` when it is too large to embed or unreadable.
fn image_src(p: &Path) -> Option<String> {
    let m = std::fs::metadata(p).ok().filter(|m| m.len() <= MAX_EMBED_BYTES)?;
    let bytes = std::fs::read(p).ok().filter(|b| b.len() as u64 == m.len())?;
    Some(format!("data:image/png;base64,{}", base64::engine::general_purpose::STANDARD.encode(bytes)))
}

/// The page of `b`, deterministic: the same bundle gives the same bytes.
///
/// # Errors
/// `resource.output` when a listed file cannot be hashed.
pub fn render(b: &Bundle) -> Result<String> {
    let images: Vec<(String, Option<String>)> = b.pictures.iter().map(|(k, p)| (k.clone(), image_src(p))).collect();
    let thumb = images.iter().find(|(k, _)| k == "thumbnail").and_then(|(_, s)| s.as_deref());
    let style_hash = {
        let d = <sha2::Sha256 as sha2::Digest>::digest(page::STYLE.as_bytes());
        base64::engine::general_purpose::STANDARD.encode(d)
    };
    let csp = format!(
        "default-src 'none'; img-src data:; style-src 'sha256-{style_hash}'; base-uri 'none'; form-action 'none'"
    );
    let mut s = String::with_capacity(4 << 20);
    s.push_str("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">");
    s.push_str(&format!("<meta http-equiv=\"Content-Security-Policy\" content=\"{csp}\">"));
    s.push_str("<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">");
    s.push_str("<meta name=\"referrer\" content=\"no-referrer\">");
    s.push_str(&format!("<title>{} - scanstation report</title>", esc(&b.title)));
    s.push_str(&format!("<style>{}</style></head><body>", page::STYLE));
    s.push_str(&page::header(b, thumb));
    s.push_str(&page::error(b));
    s.push_str(&page::gates(b));
    s.push_str(&page::pictures(&images));
    s.push_str(&page::stages(b));
    s.push_str(&page::caps(b));
    s.push_str(&page::scan(b));
    s.push_str(&page::fea(b));
    s.push_str(&page::provenance(b, &file_digests(b)?));
    s.push_str("<footer><p>scanstation ");
    s.push_str(env!("CARGO_PKG_VERSION"));
    s.push_str("</p></footer></body></html>\n");
    Ok(s)
}

/// Each listed file's name, size and SHA-256.
fn file_digests(b: &Bundle) -> Result<Vec<(String, FileDigest)>> {
    b.files
        .iter()
        .map(|p| {
            let name = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let bytes = std::fs::metadata(p).map(|m| m.len()).unwrap_or(0);
            Ok((name, FileDigest { bytes, sha256: super::provenance::sha256_file(p)? }))
        })
        .collect()
}

/// Make the page of the bundle in `dir` and write it as `<stem>.report.html` there (atomically).
///
/// # Errors
/// As [`Bundle::load`] and [`render`]; `resource.output` when it cannot be written.
pub fn write_report_html(dir: &Path) -> Result<(PathBuf, FileDigest)> {
    let b = Bundle::load(dir)?;
    let page = render(&b)?;
    let path = b.page_path();
    let digest = write_atomic(&path, |w| std::io::Write::write_all(w, page.as_bytes()))?;
    Ok((path, digest))
}

/// The page of a `convert` run that drew its pictures, beside its STEP file (`NAME.report.html`), from the
/// report in memory and the files it lists.
///
/// # Errors
/// As [`render`]; `resource.output` when it cannot be written.
pub fn write_convert_page(report: &super::convert::ConvertReport) -> Result<(PathBuf, FileDigest)> {
    let step = &report.output_file;
    let dir = step.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")).to_path_buf();
    let stem = step.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "scan".into());
    let mut files = vec![step.clone(), report.solid_mesh_file.clone(), report.error_map_file.clone()];
    files.extend(report.pictures.iter().map(|p| p.file.clone()));
    let mut b = Bundle {
        dir,
        stem,
        report: Some(serde_json::to_value(report).map_err(|e| Error::internal(format!("the report as JSON: {e}")))?),
        pictures: report.pictures.iter().map(|p| (p.kind.to_string(), p.file.clone())).collect(),
        files,
        ..Default::default()
    };
    b.title = title(&b);
    let page = render(&b)?;
    let path = convert_page_path(step);
    let digest = write_atomic(&path, |w| std::io::Write::write_all(w, page.as_bytes()))?;
    Ok((path, digest))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::raster::Image;

    /// A bundle with markup in its input's name, one picture and one too large to embed: the name is text,
    /// the picture a `data:` URI, the large one named, the gate's value as the JSON holds it, and the policy
    /// set; the same bundle gives the same bytes.
    #[test]
    fn a_page_escapes_names_embeds_pictures_and_repeats() {
        let dir = std::env::temp_dir().join(format!("scanstation-page-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let report = serde_json::json!({
            "input": "<b onmouseover=x>bust<b>.ply",
            "convert": {"status": "ok", "gates": [
                {"name": "rms", "value": 0.012345678901234567, "bound": 0.05, "unit": "%", "passed": true, "what": "<i>"}
            ]}
        });
        std::fs::write(dir.join("bust.report.json"), report.to_string()).unwrap();
        crate::geometry::io::write_png(&dir.join("bust.deviation.png"), &Image::filled(8, 8, [1, 2, 3])).unwrap();
        std::fs::write(dir.join("bust.net.png"), vec![0u8; (MAX_EMBED_BYTES + 1) as usize]).unwrap();
        let b = Bundle::load(&dir).unwrap();
        assert_eq!((b.stem.as_str(), b.title.as_str()), ("bust", "<b onmouseover=x>bust<b>.ply"));
        let page = render(&b).unwrap();
        assert!(page.contains("&lt;b onmouseover=x&gt;bust&lt;b&gt;.ply") && !page.contains("<b onmouseover"), "name");
        assert!(!page.contains("<i>") && page.contains("&lt;i&gt;"), "the gate's text is escaped");
        assert_eq!(page.matches("data:image/png;base64,").count(), 1, "one picture embedded");
        assert!(page.contains("The net picture is in the bundle but too large to embed here."));
        let value = serde_json::json!(0.012345678901234567_f64).to_string();
        assert!(page.contains(&format!("<td>{value}</td>")), "the value as the JSON writes it: {value}");
        assert!(page.contains("default-src 'none'; img-src data:; style-src 'sha256-"));
        assert!(!page.contains("<script"));
        assert_eq!(page, render(&Bundle::load(&dir).unwrap()).unwrap(), "the same bytes again");
        std::fs::remove_file(dir.join("bust.report.json")).unwrap();
        let e = Bundle::load(&dir).unwrap_err();
        assert_eq!(e.code, ErrorCode::InputNoGeometry, "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
