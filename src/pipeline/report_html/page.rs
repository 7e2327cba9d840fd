//! The report page's sections, each from the bundle's JSON records. Every string from the records is
//! escaped ([`super::html::esc`]); numbers are written as the JSON holds them.

use serde_json::Value;

use super::Bundle;
use super::html::{cell, esc, facts, section, table};

/// The page's style sheet. The Content-Security-Policy allows exactly this block by its hash.
pub const STYLE: &str = "body{font-family:system-ui,sans-serif;margin:0 auto;max-width:72rem;padding:1rem;\
color:#222;line-height:1.4}h1{font-size:1.4rem;overflow-wrap:anywhere}h2{font-size:1.15rem;margin-top:2rem;\
border-bottom:1px solid #ccc}.status{display:inline-block;padding:.1rem .6rem;border-radius:.3rem;\
font-weight:600}.ok{background:#d9f0d3}.degraded{background:#fee08b}.failed,.quarantined{background:#f4a582}\
figure{margin:1rem 0}figcaption{font-size:.9rem;color:#555}img{max-width:100%;height:auto;\
border:1px solid #ddd}.thumb{float:right;width:8rem;margin:0 0 1rem 1rem}.scroll{overflow-x:auto}\
table{border-collapse:collapse;font-size:.9rem}td,th{border-bottom:1px solid #ddd;padding:.25rem .5rem;\
text-align:left;vertical-align:top}.pass{color:#1a7f37}.miss{color:#b42318;font-weight:600}\
dl.facts{display:grid;grid-template-columns:max-content 1fr;gap:.2rem 1rem}dd{margin:0;overflow-wrap:anywhere}\
.error{border-left:4px solid #b42318;padding:.5rem 1rem;background:#fdecea}code{overflow-wrap:anywhere}";

/// What a picture kind shows, in the order the page shows them.
pub const PICTURES: [(&str, &str); 7] = [
    (
        "deviation",
        "Deviation of the solid from the scan: blue inside, red outside, grey within the tolerance band; invented surface hatched.",
    ),
    ("histogram", "How the deviations are distributed over the surface the scan saw."),
    ("net", "The quad control net over the shaded solid; red dots are extraordinary vertices."),
    ("faces", "The B-rep faces of the solid, each in its own colour."),
    ("coverage", "How many views of the scan saw each part of the surface; unseen surface hatched red."),
    ("stress", "Von Mises stress of the FEA on the solid; supports hatched black, loads hatched magenta."),
    ("convergence", "The solid's RMS distance at each attempt of the chain, against the RMS gate."),
];

/// The conversion report inside the bundle's report (the daemon wraps it as `convert`).
fn convert(b: &Bundle) -> Option<&Value> {
    let r = b.report.as_ref()?;
    Some(r.get("convert").unwrap_or(r))
}

/// The job's status: the error's class when it was quarantined, else the conversion's status.
pub fn status(b: &Bundle) -> String {
    if b.error.is_some() {
        return "quarantined".into();
    }
    convert(b).and_then(|c| c.get("status")).and_then(Value::as_str).unwrap_or("unknown").into()
}

/// The header: the name, the status, the thumbnail and the headline figures.
pub fn header(b: &Bundle, thumbnail: Option<&str>) -> String {
    let st = status(b);
    let mut s = String::new();
    if let Some(src) = thumbnail {
        s.push_str(&format!("<img class=\"thumb\" id=\"thumbnail\" alt=\"thumbnail\" src=\"{src}\">"));
    }
    s.push_str(&format!(
        "<h1 id=\"title\">{}</h1><p><span class=\"status {}\" id=\"status\">{}</span></p>",
        esc(&b.title),
        esc(&st),
        esc(&st)
    ));
    let mut pairs = Vec::new();
    let top = b.report.as_ref().or(b.error.as_ref());
    for (label, key) in [("job", "job_id"), ("input", "input")] {
        if let Some(v) = top.and_then(|r| r.get(key)) {
            pairs.push((label, cell(v)));
        }
    }
    if let Some(c) = convert(b) {
        let get = |k: &str| c.get(k).cloned().unwrap_or(Value::Null);
        pairs.push(("input vertices", cell(&get("input_vertices"))));
        pairs.push(("bounding-box diagonal", format!("{} {}", cell(&get("bbox_diagonal")), cell(&get("unit")))));
        pairs.push(("B-rep faces", cell(c.pointer("/brep/faces").unwrap_or(&Value::Null))));
        pairs.push(("volume error, %", cell(&get("volume_error_pct"))));
        if let Some(t) = c.get("far_tail").filter(|t| t.is_object()) {
            pairs.push(("far tail: scan → solid at most", far_tail(t)));
        }
        if let (Some(z), Some(d)) =
            (c.pointer("/remesh/sizing").filter(|z| z.is_object()), get("bbox_diagonal").as_f64())
        {
            pairs.push(("sizing field: lattice step asked", sizing(z, d)));
        }
        pairs.push(("attempts", c.get("attempts").and_then(Value::as_array).map_or(0, Vec::len).to_string()));
        let raises: Vec<String> = c
            .get("attempts")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
            .flat_map(|a| a.get("raises").and_then(Value::as_array).cloned().unwrap_or_default())
            .map(|x| {
                let kept = if x.get("kept") == Some(&Value::Bool(true)) { "kept" } else { "not kept" };
                format!("{} → {} ({kept})", cell(&x["from_vertices"]), cell(&x["to_vertices"]))
            })
            .collect();
        if !raises.is_empty() {
            pairs.push(("nets made finer (deviation goal)", raises.join("; ")));
        }
        // The solid's attempt: the last one.
        let local = c.get("attempts").and_then(Value::as_array).and_then(|a| a.last()).and_then(|a| a.get("local"));
        if let Some(l) = local.filter(|l| !l["kept"].is_null() || l["given_up"].as_u64().unwrap_or(0) > 0) {
            let added = l.pointer("/kept/vertices_after").and_then(Value::as_u64).unwrap_or(0)
                - l.pointer("/kept/vertices_before").and_then(Value::as_u64).unwrap_or(0);
            let text = format!(
                "{added} control vertices added where the scan passed far; {} refined nets given up",
                cell(&l["given_up"])
            );
            pairs.push(("net refined locally (deviation goal)", text));
        }
        pairs.push(("total seconds", cell(&get("total_seconds"))));
    }
    s.push_str(&facts(&pairs));
    s
}

/// The sizing field as a person reads it: the smallest and the median spacing the net was asked for against
/// the uniform one (three significant digits, % of the diagonal), and the share of the area thin or bent
/// enough to ask for a finer one.
fn sizing(z: &Value, diagonal: f64) -> String {
    let pct = |k: &str| {
        let x = z.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN);
        crate::pipeline::pictures::sheet::num(100.0 * x / diagonal)
    };
    let share = |k: &str| format!("{:.1}", 100.0 * z.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN));
    esc(&format!(
        "{} % of the diagonal at least, {} % median (uniform {} %; the net's spacing about half of it); thin {} %, bent {} % of the area",
        pct("min_spacing"),
        pct("median_spacing"),
        pct("uniform_spacing"),
        share("thin_share"),
        share("curved_share")
    ))
}

/// The far tail as a person reads it: the largest scan → solid distance (three significant digits), the
/// scan beyond the far-tail goal (ringed on the deviation map), and what repair left.
fn far_tail(t: &Value) -> String {
    let num = |k: &str| t.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN);
    let count = |k: &str| t.get(k).and_then(Value::as_u64).unwrap_or(0);
    let places = t.get("places").and_then(Value::as_array).map_or(0, Vec::len);
    let mut text = format!(
        "{} % of the diagonal; {} scan vertices beyond the goal of {} % ({places} places, ringed on the deviation map)",
        crate::pipeline::pictures::sheet::num(num("max_pct")),
        count("vertices_beyond_goal"),
        crate::pipeline::pictures::sheet::num(num("goal_pct")),
    );
    if count("dropped_by_repair") > 0 {
        text.push_str(&format!(
            "; {} scan vertices repair left farther than the goal (up to {} %), not judged",
            count("dropped_by_repair"),
            crate::pipeline::pictures::sheet::num(num("dropped_max_pct"))
        ));
    }
    esc(&text)
}

/// Why a quarantined job stopped.
pub fn error(b: &Bundle) -> String {
    let Some(e) = &b.error else { return String::new() };
    let get = |k: &str| e.get(k).map(cell).unwrap_or_default();
    let body = format!(
        "<div class=\"error\" id=\"error\"><p><code>{}</code> in stage <code>{}</code></p><p>{}</p><p>{}</p></div>",
        get("error_code"),
        get("stage"),
        get("message"),
        get("hint")
    );
    section("why", "Why it was stopped", &body)
}

/// The quality gates with their values and bounds (`#gates`: one row per gate, the value in the second
/// column exactly as the report's JSON holds it).
pub fn gates(b: &Bundle) -> String {
    let Some(gates) = convert(b).and_then(|c| c.get("gates")).and_then(Value::as_array) else { return String::new() };
    let rows: Vec<Vec<String>> = gates
        .iter()
        .map(|g| {
            let get = |k: &str| g.get(k).cloned().unwrap_or(Value::Null);
            let passed = get("passed").as_bool().unwrap_or(false);
            vec![
                cell(&get("name")),
                cell(&get("value")),
                cell(&get("bound")),
                cell(&get("unit")),
                format!(
                    "<span class=\"{}\">{}</span>",
                    if passed { "pass" } else { "miss" },
                    if passed { "met" } else { "missed" }
                ),
                cell(&get("what")),
            ]
        })
        .collect();
    section("quality", "Quality gates", &table("gates", &["gate", "value", "bound", "unit", "result", "what"], &rows))
}

/// The pictures, as `<figure>`s (`images`: kind → the `data:` URI, or `None` for one too large to embed,
/// which is named instead).
pub fn pictures(images: &[(String, Option<String>)]) -> String {
    let mut body = String::new();
    for (kind, what) in PICTURES {
        match images.iter().find(|(k, _)| k == kind) {
            Some((_, Some(src))) => body.push_str(&format!(
                "<figure id=\"picture-{kind}\"><img alt=\"{kind}\" src=\"{src}\"><figcaption>{}</figcaption></figure>",
                esc(what)
            )),
            Some((_, None)) => body.push_str(&format!(
                "<p id=\"picture-{kind}\">The {kind} picture is in the bundle but too large to embed here.</p>"
            )),
            None => {}
        }
    }
    if body.is_empty() { String::new() } else { section("pictures", "Pictures", &body) }
}

/// Time, memory and distance after every stage.
pub fn stages(b: &Bundle) -> String {
    let Some(stages) = convert(b).and_then(|c| c.get("stages")).and_then(Value::as_array) else { return String::new() };
    let rows: Vec<Vec<String>> = stages
        .iter()
        .map(|s| {
            let p = |ptr: &str| cell(s.pointer(ptr).unwrap_or(&Value::Null));
            vec![p("/stage"), p("/seconds"), p("/peak_rss_mib"), p("/distance/symmetric/rms/pct_of_diagonal")]
        })
        .collect();
    let head = ["stage", "seconds", "peak memory, MiB", "RMS to the input, % of diagonal"];
    section("stages", "Stages", &table("stage-table", &head, &rows))
}

/// An open input's caps and invented surface, and what repair filled.
pub fn caps(b: &Bundle) -> String {
    let Some(c) = convert(b) else { return String::new() };
    let mut body = String::new();
    if let Some(h) = c.pointer("/repair/holes").filter(|h| h.is_object()) {
        body.push_str(&facts(&scalars(h)));
    }
    if let Some(o) = c.get("open_input").filter(|o| o.is_object()) {
        body.push_str(&facts(&scalars(o)));
    }
    if body.is_empty() { String::new() } else { section("caps", "Holes, caps and invented surface", &body) }
}

/// A scan's views, their residuals and the coverage.
pub fn scan(b: &Bundle) -> String {
    let Some(f) = &b.fusion else { return String::new() };
    let rows: Vec<Vec<String>> = f
        .get("views")
        .and_then(Value::as_array)
        .map(|views| {
            views
                .iter()
                .map(|v| {
                    let p = |ptr: &str| cell(v.pointer(ptr).unwrap_or(&Value::Null));
                    vec![
                        p("/index"),
                        p("/file"),
                        p("/angle_deg"),
                        p("/tilt_deg"),
                        p("/pass"),
                        p("/points"),
                        p("/gain"),
                        p("/chosen/round"),
                        p("/status"),
                        p("/residual_before_refinement/residual_rms"),
                        p("/residual_after_refinement/residual_rms"),
                    ]
                })
                .collect()
        })
        .unwrap_or_default();
    let head = [
        "view",
        "file",
        "angle, deg",
        "tilt, deg",
        "pass",
        "points",
        "gain (share first seen)",
        "chosen in round",
        "status",
        "residual before",
        "residual after",
    ];
    let mut body = table("views", &head, &rows);
    // Each later pass: how it was found in the first's frame.
    let passes: Vec<Vec<String>> = f
        .pointer("/passes/aligned")
        .and_then(Value::as_array)
        .map(|ps| {
            ps.iter()
                .map(|a| {
                    let p = |ptr: &str| cell(a.pointer(ptr).unwrap_or(&Value::Null));
                    vec![
                        p("/pass"),
                        p("/views"),
                        p("/turned_deg"),
                        p("/overlap"),
                        p("/residual_rms"),
                        p("/residual_limit"),
                    ]
                })
                .collect()
        })
        .unwrap_or_default();
    if !passes.is_empty() {
        let head = ["pass", "views", "turned over, deg", "overlap", "residual", "residual limit"];
        body.push_str(&table("passes", &head, &passes));
    }
    let p = |ptr: &str| cell(f.pointer(ptr).unwrap_or(&Value::Null));
    body.push_str(&facts(&[
        ("coverage (share of the surface seen)", p("/coverage/share")),
        ("unseen surface (share of the solid's area)", p("/unseen/share")),
        (
            "largest unseen patch (share, at)",
            format!("{} at {}", p("/unseen/largest_patch_share"), p("/unseen/largest_patch_at")),
        ),
        (
            "views chosen where the surface was unseen (target, end)",
            format!("{} ({})", p("/next_views/coverage_target"), p("/next_views/end")),
        ),
        ("fusion", p("/decision")),
        (
            "pooled residual before / after",
            format!("{} / {}", p("/pooled_residual_before"), p("/pooled_residual_after")),
        ),
    ]));
    section("scan", "Scan: views and residuals", &body)
}

/// The FEA's headline figures.
pub fn fea(b: &Bundle) -> String {
    let Some(f) = &b.fea else { return String::new() };
    section("fea", "FEA", &facts(&scalars(f)))
}

/// Provenance: the input's hash, the daemon's version and configuration, and every file of the bundle
/// (but the page and the manifest, which are written after it) with its size and hash.
pub fn provenance(b: &Bundle, files: &[(String, crate::geometry::io::FileDigest)]) -> String {
    let mut pairs = Vec::new();
    let top = b.report.as_ref().or(b.error.as_ref());
    for (label, key) in [
        ("input", "input"),
        ("input SHA-256", "input_sha256"),
        ("input SHA-256", "sha256"),
        ("configuration digest", "config_digest"),
        ("daemon version", "daemon_version"),
    ] {
        if let Some(v) = top.and_then(|r| r.get(key)) {
            pairs.push((label, format!("<code>{}</code>", cell(v))));
        }
    }
    let mut body = facts(&pairs);
    let rows: Vec<Vec<String>> = files
        .iter()
        .map(|(name, d)| vec![esc(name), d.bytes.to_string(), format!("<code>{}</code>", esc(&d.sha256))])
        .collect();
    body.push_str(&table("files", &["file", "bytes", "SHA-256"], &rows));
    section("provenance", "Provenance", &body)
}

/// The scalar members of an object (one level of nesting as `a.b`), as facts.
fn scalars(v: &Value) -> Vec<(String, String)> {
    let mut out = Vec::new();
    if let Some(o) = v.as_object() {
        for (k, x) in o {
            match x {
                Value::Object(inner) => {
                    for (k2, y) in inner.iter().filter(|(_, y)| !y.is_object() && !y.is_array()) {
                        out.push((format!("{k}.{k2}"), cell(y)));
                    }
                }
                Value::Array(_) => {}
                _ => out.push((k.clone(), cell(x))),
            }
        }
    }
    out
}
