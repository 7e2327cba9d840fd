//! Job pictures and report pages, from outside: the `scanstation` binary's `convert --pictures`, `render`
//! and `report`, and the pages opened in a real browser (Debian's headless `chromium`, installed by
//! `scripts/setup-daemon-tests.sh`; a missing one fails the test saying so).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_scanstation"))
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn run(cmd: &mut Command) -> std::process::Output {
    let out = cmd.output().unwrap();
    assert!(out.status.success(), "{cmd:?}: {}", String::from_utf8_lossy(&out.stderr));
    out
}

/// Width and height of a PNG from its IHDR.
fn png_size(p: &Path) -> (u32, u32) {
    let b = std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    assert_eq!(&b[..8], b"\x89PNG\r\n\x1a\n", "{}: not a PNG", p.display());
    (u32::from_be_bytes(b[16..20].try_into().unwrap()), u32::from_be_bytes(b[20..24].try_into().unwrap()))
}

/// `convert --pictures` writes every picture and a page that a browser shows whole: every picture loaded,
/// no console error, nothing fetched, the gate table equal to the report's gates, no wider than a phone.
/// `report DIR` makes the page again, the same bytes each time.
#[test]
fn a_converted_scan_gets_pictures_and_a_page_a_browser_shows_whole() {
    let dir = common::scratch("report-convert");
    let step = dir.join("spot.step");
    let json = dir.join("spot.report.json");
    run(bin()
        .arg("convert")
        .arg(root().join("examples/spot.ply"))
        .arg("-o")
        .arg(&step)
        .arg("--report")
        .arg(&json)
        .arg("--pictures"));
    for (kind, size) in [
        ("deviation", (1024, 768)),
        ("net", (1024, 768)),
        ("faces", (1024, 768)),
        ("histogram", (1024, 384)),
        ("thumbnail", (256, 256)),
    ] {
        assert_eq!(png_size(&dir.join(format!("spot.{kind}.png"))), size, "spot.{kind}.png");
    }
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let kinds: Vec<&str> = report["pictures"].as_array().unwrap().iter().map(|p| p["kind"].as_str().unwrap()).collect();
    assert_eq!(kinds, ["deviation", "histogram", "net", "faces", "thumbnail"], "one attempt: no convergence plot");
    let page = dir.join("spot.report.html");
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.contains("Content-Security-Policy") && html.contains("default-src 'none'"), "no CSP");
    assert!(html.len() < 3 << 20, "page of {} bytes", html.len());

    let seen = common::browser_check(&page, "spot-convert", 1280);
    common::assert_safe_page(&page, &seen, 5); // the thumbnail and four pictures
    common::assert_gates_match(&page, &seen, &report["gates"]);
    assert_eq!(seen["title"], "spot.ply");
    let phone = common::browser_check(&page, "spot-convert-phone", 390);
    assert!(phone["page_width"].as_u64().unwrap() <= 390, "wider than a phone: {}", phone["page_width"]);

    // `report DIR`: the directory holds NAME.report.json, so it is a bundle; the page is made again.
    let first = run(bin().args(["report", "--json"]).arg(&dir));
    let v: serde_json::Value = serde_json::from_slice(&first.stdout).unwrap();
    assert_eq!(v["file"], page.display().to_string());
    let bytes = std::fs::read(&page).unwrap();
    run(bin().arg("report").arg(&dir));
    assert!(bytes == std::fs::read(&page).unwrap(), "the page changed when made again from the same bundle");
    let seen = common::browser_check(&page, "spot-report-again", 1280);
    common::assert_safe_page(&page, &seen, 5);
    common::assert_gates_match(&page, &seen, &report["gates"]);
}

/// `render` draws each colouring as one 1024 × 768 sheet; what a colouring needs and lacks is a clean error.
#[test]
fn render_draws_each_colouring_and_refuses_what_it_cannot() {
    let dir = common::scratch("report-render");
    let spot = root().join("examples/spot.ply");
    let rod = root().join("examples/rod.ply");
    for (mesh, by, extra) in [
        (&spot, "deviation", vec!["--ref".to_string(), spot.display().to_string()]),
        (&spot, "net", vec![]),
        (&spot, "faces", vec![]),
        (
            &rod,
            "stress",
            vec!["--spec".to_string(), root().join("config/fea/cantilever-rod.toml").display().to_string()],
        ),
    ] {
        let out = dir.join(format!("{by}.png"));
        run(bin().arg("render").arg(mesh).args(["--color-by", by]).args(&extra).arg("-o").arg(&out));
        assert_eq!(png_size(&out), (1024, 768), "{by}");
    }
    // Deviation without a reference, coverage of a mesh that is no scan set, an output over the input.
    for (args, code) in [
        (vec!["--color-by", "deviation"], "input.bad-argument"),
        (vec!["--color-by", "coverage", "--ref", spot.to_str().unwrap()], "input"),
    ] {
        let out =
            bin().arg("render").arg(&spot).args(&args).arg("-o").arg(dir.join("x.png")).arg("--json").output().unwrap();
        assert!(!out.status.success(), "{args:?} succeeded");
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert!(v["error"]["code"].as_str().unwrap().starts_with(code), "{args:?}: {v}");
    }
    let out = bin().arg("render").arg(&spot).args(["--color-by", "net", "-o"]).arg(&spot).output().unwrap();
    assert!(!out.status.success(), "render over its own input");
    assert!(std::fs::read(&spot).unwrap().starts_with(b"ply"), "the input survived");
}

/// `report` on what is no bundle is a clean error with a stable code.
#[test]
fn report_refuses_a_directory_that_is_no_bundle() {
    let dir = common::scratch("report-none");
    std::fs::write(dir.join("notes.txt"), "nothing").unwrap();
    let out = bin().args(["report", "--json"]).arg(&dir).output().unwrap();
    assert!(!out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["error"]["code"], "input.no-geometry", "{v}");
    let out = bin().args(["report", "--json"]).arg(dir.join("missing")).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["error"]["code"], "input.not-found", "{v}");
    std::fs::write(dir.join("x.report.json"), "{ not json").unwrap();
    let out = bin().args(["report", "--json"]).arg(&dir).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["error"]["code"], "input.bad-header", "{v}");
}
