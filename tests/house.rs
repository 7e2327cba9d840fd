//! The house rules, checked on the source itself: the layering (which layer may import which), and the size
//! limits that keep drivers readable (function length, parameter count, file length).
//!
//! Layers, bottom up (README, "Layout"):
//! * `src/geometry` imports nothing above it (no `stages`, `pipeline`, `daemon`, `devices`);
//! * a stage (`src/stages/<stage>`) imports geometry, the stage root (`Progress`, `NoProgress`) and the
//!   distance measure `quality::{compare, CompareOptions, DistanceReport, DistanceStats}`, never another stage's
//!   internals, nor the pipeline or the daemon;
//! * `src/pipeline` never imports the daemon;
//! * `src/devices` imports neither the stages, the pipeline nor the daemon;
//! * `src/daemon` imports no stage: it reaches them only through the pipeline;
//! * nothing below the daemon (geometry, stages, pipeline) names tokio, zbus, inotify, futures or journald.
//!
//! Limits everywhere in `src`: no function over [`MAX_FN_LINES`] lines, no file over [`MAX_FILE_LINES`] lines,
//! no function with more than [`MAX_PARAMS`] parameters (`self` not counted). Run with `--nocapture` for the
//! table of the largest ones.
//!
//! No circles: no set of files imports itself round (`a.rs` names `b.rs`, which names `a.rs`, directly or
//! through others). A module's root file naming its own submodules (`mod x; pub use x::Y;`) is a declaration,
//! not an import, and is not counted.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Lines of one function, from its `fn` line to its closing brace.
const MAX_FN_LINES: usize = 150;
/// Lines of one file.
const MAX_FILE_LINES: usize = 1000;
/// Parameters of one function, `self` not counted.
const MAX_PARAMS: usize = 7;
/// The folders the length limits hold in.
const LIMITED: [&str; 1] = ["src"];
/// What only the daemon layer (and the binaries above it) may name.
const ASYNC_CRATES: [&str; 5] = ["tokio", "zbus", "inotify", "futures_util", "tracing_journald"];
/// What a stage may import from the quality stage: the two-sided distance every stage reports with.
const COMPARE_API: [&str; 4] = ["compare", "CompareOptions", "DistanceReport", "DistanceStats"];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Every `.rs` file under `dir`, sorted, as paths relative to the repository root.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![root().join(dir)];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display())) {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p.strip_prefix(root()).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// The source with comments, string and char literals blanked (newlines kept, so line numbers hold).
fn code_only(src: &str) -> String {
    let b = src.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    let blank = |out: &mut Vec<u8>, c: u8| out.push(if c == b'\n' { b'\n' } else { b' ' });
    while i < b.len() {
        let c = b[i];
        if c == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                blank(&mut out, b[i]);
                i += 1;
            }
        } else if c == b'/' && b.get(i + 1) == Some(&b'*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
                    depth += 1;
                    out.extend(b"  ");
                    i += 2;
                } else if b[i] == b'*' && b.get(i + 1) == Some(&b'/') {
                    depth -= 1;
                    out.extend(b"  ");
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    blank(&mut out, b[i]);
                    i += 1;
                }
            }
        } else if c == b'r' && (b.get(i + 1) == Some(&b'#') || b.get(i + 1) == Some(&b'"')) && !ident_before(b, i) {
            // Raw string r#"…"#.
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&b'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&b'"') {
                out.push(c);
                i += 1;
                continue;
            }
            j += 1;
            loop {
                if j >= b.len() {
                    break;
                }
                if b[j] == b'"' && b[j + 1..].iter().take(hashes).filter(|&&h| h == b'#').count() == hashes {
                    j += 1 + hashes;
                    break;
                }
                j += 1;
            }
            for &x in &b[i..j.min(b.len())] {
                blank(&mut out, x);
            }
            i = j;
        } else if c == b'"' {
            blank(&mut out, c);
            i += 1;
            while i < b.len() && b[i] != b'"' {
                if b[i] == b'\\' {
                    blank(&mut out, b[i]);
                    i += 1;
                }
                if i < b.len() {
                    blank(&mut out, b[i]);
                    i += 1;
                }
            }
            if i < b.len() {
                blank(&mut out, b[i]);
                i += 1;
            }
        } else if c == b'\'' {
            // A char literal ('x', '\n', '\u{..}') or a lifetime ('a): blank only the former.
            let end = if b.get(i + 1) == Some(&b'\\') {
                b[i + 2..].iter().position(|&x| x == b'\'').map(|k| i + 2 + k)
            } else if b.get(i + 2) == Some(&b'\'') {
                Some(i + 2)
            } else {
                None
            };
            match end {
                Some(e) => {
                    for &x in &b[i..=e] {
                        blank(&mut out, x);
                    }
                    i = e + 1;
                }
                None => {
                    out.push(c);
                    i += 1;
                }
            }
        } else {
            out.push(c);
            i += 1;
        }
    }
    String::from_utf8(out).unwrap()
}

fn ident_before(b: &[u8], i: usize) -> bool {
    i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_')
}

fn is_ident(c: u8) -> bool {
    c.is_ascii_alphanumeric() || c == b'_'
}

/// One function: its name, first line (1-based), length in lines and parameter count (`self` not counted).
#[derive(Debug)]
struct Func {
    name: String,
    line: usize,
    lines: usize,
    params: usize,
}

/// The functions of a file (trait declarations without a body count for parameters, with one line).
fn functions(code: &str) -> Vec<Func> {
    let b = code.as_bytes();
    let line_of = |at: usize| code[..at].bytes().filter(|&c| c == b'\n').count() + 1;
    let mut out = Vec::new();
    let mut i = 0;
    while let Some(k) = code[i..].find("fn ") {
        let at = i + k;
        i = at + 3;
        if ident_before(b, at) {
            continue;
        }
        let mut j = at + 3;
        while j < b.len() && b[j] == b' ' {
            j += 1;
        }
        let start = j;
        while j < b.len() && is_ident(b[j]) {
            j += 1;
        }
        if j == start {
            continue;
        }
        let name = code[start..j].to_string();
        // Generic parameters, then the parameter list.
        let Some(open) = code[j..].find('(').map(|k| j + k) else { continue };
        let mut depth = 0i32;
        let mut commas = 0;
        let mut close = open;
        let mut last_nonspace = b'(';
        for (k, &c) in b.iter().enumerate().skip(open) {
            match c {
                b'(' | b'[' | b'{' => depth += 1,
                b')' | b']' | b'}' => depth -= 1,
                b'<' => depth += 1,
                b'>' if b[k - 1] != b'-' && b[k - 1] != b'=' => depth -= 1,
                b',' if depth == 1 => commas += 1,
                _ => {}
            }
            if depth == 0 {
                close = k;
                break;
            }
            if !c.is_ascii_whitespace() {
                last_nonspace = c;
            }
        }
        let inner = code[open + 1..close].trim();
        let mut params = if inner.is_empty() { 0 } else { commas + usize::from(last_nonspace != b',') };
        let first = inner.split(',').next().unwrap_or("").trim();
        if first.ends_with("self") || first.starts_with("self") || first.starts_with("mut self") {
            params = params.saturating_sub(1);
        }
        // The body: the first `{` or `;` after the parameters at bracket depth 0.
        let mut k = close + 1;
        let mut d = 0i32;
        while k < b.len() {
            match b[k] {
                b'(' | b'[' | b'<' => d += 1,
                b')' | b']' => d -= 1,
                b'>' if b[k - 1] != b'-' => d -= 1,
                b'{' | b';' if d <= 0 => break,
                _ => {}
            }
            k += 1;
        }
        let lines = if k < b.len() && b[k] == b'{' {
            let mut depth = 0;
            let mut end = k;
            for (e, &c) in b.iter().enumerate().skip(k) {
                if c == b'{' {
                    depth += 1;
                } else if c == b'}' {
                    depth -= 1;
                    if depth == 0 {
                        end = e;
                        break;
                    }
                }
            }
            line_of(end) - line_of(at) + 1
        } else {
            1
        };
        out.push(Func { name, line: line_of(at), lines, params });
    }
    out
}

/// Every path a file names through `crate::…` (use trees expanded), as `a::b::c` without the `crate::`.
fn crate_paths(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut i = 0;
    while let Some(k) = code[i..].find("crate::") {
        let at = i + k;
        i = at + 7;
        if ident_before(code.as_bytes(), at) {
            continue;
        }
        expand(&code[at + 7..], String::new(), &mut out);
    }
    out
}

/// Expands one path or use tree starting at `s` with `prefix` (`a::{b, c::d}` → `a::b`, `a::c::d`).
fn expand(s: &str, prefix: String, out: &mut Vec<String>) {
    let b = s.as_bytes();
    let mut j = 0;
    let mut path = prefix;
    loop {
        while j < b.len() && b[j].is_ascii_whitespace() {
            j += 1;
        }
        if j < b.len() && b[j] == b'{' {
            // A group: split at top-level commas.
            let mut depth = 0;
            let mut start = j + 1;
            for k in j..b.len() {
                match b[k] {
                    b'{' => depth += 1,
                    b'}' => {
                        depth -= 1;
                        if depth == 0 {
                            expand(&s[start..k], path.clone(), out);
                            return;
                        }
                    }
                    b',' if depth == 1 => {
                        expand(&s[start..k], path.clone(), out);
                        start = k + 1;
                    }
                    _ => {}
                }
            }
            return;
        }
        let start = j;
        while j < b.len() && is_ident(b[j]) {
            j += 1;
        }
        if j > start {
            if !path.is_empty() {
                path.push_str("::");
            }
            path.push_str(&s[start..j]);
        }
        if s[j..].starts_with("::") {
            j += 2;
        } else {
            if !path.is_empty() {
                out.push(path);
            }
            return;
        }
    }
}

/// The stage a file belongs to (`src/stages/<stage>/…` or `src/stages/<stage>.rs`), if any.
fn stage_of(file: &Path) -> Option<String> {
    let mut parts = file.iter().map(|p| p.to_string_lossy().into_owned());
    (parts.next()? == "src" && parts.next()? == "stages").then_some(())?;
    let s = parts.next()?;
    (s != "mod.rs").then(|| s.trim_end_matches(".rs").to_string())
}

fn stages() -> Vec<String> {
    rust_files(Path::new("src/stages"))
        .iter()
        .filter_map(|f| stage_of(f))
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect()
}

/// The layering violations of one file, as messages naming the file and the path.
fn layering_violations(file: &Path, code: &str, stages: &[String]) -> Vec<String> {
    let f = file.display();
    let layer = |l: &str| file.starts_with(Path::new("src").join(l));
    let mut bad = Vec::new();
    for p in crate_paths(code) {
        let seg: Vec<&str> = p.split("::").collect();
        let top = seg[0];
        let above = match () {
            _ if layer("geometry") => ["stages", "pipeline", "daemon", "devices"].contains(&top),
            _ if layer("stages") => ["pipeline", "daemon", "devices"].contains(&top),
            _ if layer("pipeline") => ["daemon", "devices"].contains(&top),
            // Devices sit beside the pipeline, under the daemon: they use neither, nor the stages.
            _ if layer("devices") => ["stages", "pipeline", "daemon"].contains(&top),
            // The daemon reaches the stages only through the pipeline.
            _ if layer("daemon") => top == "stages",
            _ => false,
        };
        if above {
            bad.push(format!("{f}: imports crate::{p}, a higher layer"));
        }
        if let (Some(own), "stages", Some(other)) = (stage_of(file), top, seg.get(1))
            && stages.iter().any(|s| s == other)
            && *other != own
            && !(*other == "quality" && seg.len() == 3 && COMPARE_API.contains(&seg[2]))
        {
            bad.push(format!("{f}: stage `{own}` imports crate::{p}, another stage's internals"));
        }
    }
    if !layer("daemon") && !layer("bin") && !layer("devices") {
        for c in ASYNC_CRATES {
            let b = code.as_bytes();
            let mut i = 0;
            while let Some(k) = code[i..].find(c) {
                let at = i + k;
                i = at + c.len();
                if !ident_before(b, at) && code[i..].starts_with("::") {
                    bad.push(format!("{f}:{}: names `{c}` below the daemon layer", code[..at].lines().count()));
                }
            }
        }
    }
    bad
}

#[test]
fn layers_import_only_downward() {
    let stages = stages();
    assert!(stages.len() >= 6, "found the stages {stages:?} under src/stages");
    let mut bad = Vec::new();
    for file in rust_files(Path::new("src")) {
        let src = std::fs::read_to_string(root().join(&file)).unwrap();
        bad.extend(layering_violations(&file, &code_only(&src), &stages));
    }
    assert!(bad.is_empty(), "layering broken ({} places):\n{}", bad.len(), bad.join("\n"));
}

#[test]
fn the_layering_check_catches_what_it_should() {
    let stages: Vec<String> = ["quality", "remesh", "repair", "surface"].map(String::from).to_vec();
    let remesh = Path::new("src/stages/remesh/mod.rs");
    let code = code_only(
        "use crate::stages::repair::decimate::decimate;\nuse crate::stages::{Progress, quality::{compare, percentile}};\n\
         // use crate::daemon::x;\nfn f() { let s = \"crate::daemon::y\"; tokio::spawn(x); }\n",
    );
    let bad = layering_violations(remesh, &code, &stages);
    assert_eq!(bad.len(), 3, "{bad:#?}");
    assert!(bad[0].contains("repair::decimate::decimate"), "{bad:#?}");
    assert!(bad[1].contains("quality::percentile"), "{bad:#?}");
    assert!(bad[2].contains("`tokio`"), "{bad:#?}");
    let geometry = Path::new("src/geometry/mesh.rs");
    assert_eq!(layering_violations(geometry, "use crate::stages::Progress;", &stages).len(), 1);
    let pipeline = Path::new("src/pipeline/mod.rs");
    assert_eq!(layering_violations(pipeline, "use crate::daemon::Config;", &stages).len(), 1);
    let devices = Path::new("src/devices/link.rs");
    assert_eq!(layering_violations(devices, "use crate::pipeline::convert_file;", &stages).len(), 1);
    assert!(layering_violations(devices, "use crate::error::Error; fn f() { tokio::spawn(x); }", &stages).is_empty());
    assert!(layering_violations(pipeline, "use crate::stages::repair::decimate;", &stages).is_empty());
    let daemon = Path::new("src/daemon/worker.rs");
    assert_eq!(layering_violations(daemon, "fn f() { crate::stages::check_cancelled(p); }", &stages).len(), 1);
    assert!(layering_violations(daemon, "use crate::pipeline::{Progress, check_cancelled};", &stages).is_empty());
}

#[test]
fn the_size_measure_counts_lines_and_parameters() {
    let src = "impl A {\n    fn f(&self, a: u8, b: Vec<(u8, u8)>, c: &dyn Fn(u8, u8) -> u8,) -> u8 {\n        let s = '{';\n        \"}\";\n        0\n    }\n}\nfn g<T: Into<u8>>(x: T) where T: Copy { }\ntrait T { fn h(a: u8, b: u8); }\n";
    let fs = functions(&code_only(src));
    let got: Vec<(&str, usize, usize, usize)> =
        fs.iter().map(|f| (f.name.as_str(), f.line, f.lines, f.params)).collect();
    assert_eq!(got, vec![("f", 2, 5, 3), ("g", 8, 1, 1), ("h", 9, 1, 2)]);
}

#[test]
fn functions_and_files_stay_within_the_limits() {
    let mut bad = Vec::new();
    // Per area: (largest function, its lines), largest file lines, most parameters.
    let mut table: BTreeMap<String, (String, usize, String, usize, String, usize)> = BTreeMap::new();
    for file in rust_files(Path::new("src")) {
        let src = std::fs::read_to_string(root().join(&file)).unwrap();
        let limited = LIMITED.iter().any(|l| file.starts_with(l));
        let file_lines = src.lines().count();
        let area = file.parent().unwrap().display().to_string();
        let row = table.entry(area).or_default();
        if file_lines > row.3 {
            (row.2, row.3) = (file.display().to_string(), file_lines);
        }
        if limited && file_lines > MAX_FILE_LINES {
            bad.push(format!("{}: {file_lines} lines (at most {MAX_FILE_LINES})", file.display()));
        }
        for func in functions(&code_only(&src)) {
            let at = format!("{}:{} {}", file.display(), func.line, func.name);
            if func.lines > row.1 {
                (row.0, row.1) = (at.clone(), func.lines);
            }
            if func.params > row.5 {
                (row.4, row.5) = (at.clone(), func.params);
            }
            if limited && func.lines > MAX_FN_LINES {
                bad.push(format!("{at}: {} lines (at most {MAX_FN_LINES})", func.lines));
            }
            if func.params > MAX_PARAMS {
                bad.push(format!("{at}: {} parameters (at most {MAX_PARAMS})", func.params));
            }
        }
    }
    println!("| folder | longest function | lines | longest file | lines | most parameters | count |");
    println!("|---|---|---:|---|---:|---|---:|");
    for (area, (f, fl, file, l, p, pc)) in &table {
        println!("| {area} | {f} | {fl} | {file} | {l} | {p} | {pc} |");
    }
    assert!(bad.is_empty(), "over the limits ({} places):\n{}", bad.len(), bad.join("\n"));
}

/// The crate root folder of `file` and its module path inside that crate (`src/a/b.rs` → (`src`, [a, b]);
/// `src/bin/x/y.rs` → (`src/bin/x`, [y])).
fn module_of(file: &Path) -> (PathBuf, Vec<String>) {
    let parts: Vec<String> = file.iter().map(|p| p.to_string_lossy().into_owned()).collect();
    let (root, rest) = if parts.len() >= 3 && parts[1] == "bin" && !parts[2].ends_with(".rs") {
        (PathBuf::from("src/bin").join(&parts[2]), &parts[3..])
    } else if parts.len() == 3 && parts[1] == "bin" {
        (PathBuf::from("src/bin"), &parts[2..])
    } else {
        (PathBuf::from("src"), &parts[1..])
    };
    let mut m: Vec<String> = rest.iter().map(|s| s.trim_end_matches(".rs").to_string()).collect();
    if matches!(m.last().map(String::as_str), Some("mod" | "lib" | "main")) {
        m.pop();
    }
    (root, m)
}

/// The file of the longest prefix of module path `m` under crate root `root` that is a file.
fn file_of(root: &Path, m: &[String]) -> Option<PathBuf> {
    for k in (0..=m.len()).rev() {
        let base = root.join(m[..k].join("/"));
        let candidates = if k == 0 {
            vec![root.join("lib.rs"), root.join("main.rs")]
        } else {
            vec![base.with_extension("rs"), base.join("mod.rs")]
        };
        if let Some(f) = candidates.into_iter().find(|c| root_join(c).is_file()) {
            return Some(f);
        }
    }
    None
}

fn root_join(p: &Path) -> PathBuf {
    root().join(p)
}

/// The files `file` imports: every `crate::…`, `super::…` and `self::…` path resolved to the file that holds
/// it (inline test modules at the end of a file are left out). A root file's own submodules are not counted.
fn imported_files(file: &Path, code: &str) -> BTreeSet<PathBuf> {
    let code = code.split("#[cfg(test)]\nmod tests").next().unwrap_or(code);
    let (root, module) = module_of(file);
    let is_root_file = matches!(file.file_name().and_then(|n| n.to_str()), Some("mod.rs" | "lib.rs" | "main.rs"));
    let mut out = BTreeSet::new();
    for (kw, skip) in [("crate::", 0usize), ("super::", 1), ("self::", 0)] {
        let mut i = 0;
        while let Some(k) = code[i..].find(kw) {
            let at = i + k;
            i = at + kw.len();
            if ident_before(code.as_bytes(), at) || (kw != "crate::" && code[..at].ends_with("::")) {
                continue;
            }
            let mut paths = Vec::new();
            expand(&code[at + kw.len()..], String::new(), &mut paths);
            let base: Vec<String> = match kw {
                "crate::" => Vec::new(),
                _ => module[..module.len().saturating_sub(skip)].to_vec(),
            };
            for p in paths {
                let mut m = base.clone();
                for seg in p.split("::") {
                    if seg == "super" {
                        m.pop();
                    } else {
                        m.push(seg.to_string());
                    }
                }
                let Some(target) = file_of(&root, &m) else { continue };
                let (_, tm) = module_of(&target);
                let own_child = is_root_file && tm.len() > module.len() && tm.starts_with(&module);
                if target != file && !own_child {
                    out.insert(target);
                }
            }
        }
    }
    out
}

/// The import circles among `edges` (file → files it imports): each strongly connected set of two or more files.
fn circles(edges: &BTreeMap<PathBuf, BTreeSet<PathBuf>>) -> Vec<Vec<PathBuf>> {
    let reach = |from: &PathBuf| -> BTreeSet<PathBuf> {
        let mut seen = BTreeSet::new();
        let mut stack = vec![from.clone()];
        while let Some(f) = stack.pop() {
            for t in edges.get(&f).into_iter().flatten() {
                if seen.insert(t.clone()) {
                    stack.push(t.clone());
                }
            }
        }
        seen
    };
    let reached: BTreeMap<&PathBuf, BTreeSet<PathBuf>> = edges.keys().map(|f| (f, reach(f))).collect();
    let mut done = BTreeSet::new();
    let mut out = Vec::new();
    for (f, r) in &reached {
        if done.contains(*f) || !r.contains(*f) {
            continue;
        }
        let set: Vec<PathBuf> =
            r.iter().filter(|g| reached.get(g).is_some_and(|rg| rg.contains(*f))).cloned().collect();
        done.extend(set.iter().cloned());
        out.push(set);
    }
    out
}

#[test]
fn no_files_import_each_other_round() {
    let mut edges = BTreeMap::new();
    for file in rust_files(Path::new("src")) {
        let src = std::fs::read_to_string(root().join(&file)).unwrap();
        edges.insert(file.clone(), imported_files(&file, &code_only(&src)));
    }
    let found = circles(&edges);
    let text: Vec<String> =
        found.iter().map(|c| c.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(" ⇄ ")).collect();
    assert!(found.is_empty(), "import circles ({}):\n{}", found.len(), text.join("\n"));
}

#[test]
fn the_circle_check_catches_what_it_should() {
    let journal = Path::new("src/daemon/journal.rs");
    let got =
        imported_files(journal, &code_only("use super::scan::plan::Plan;\nuse crate::daemon::spool::{Spool, Job};\n"));
    let want: BTreeSet<PathBuf> = ["src/daemon/scan/plan.rs", "src/daemon/spool.rs"].map(PathBuf::from).into();
    assert_eq!(got, want);
    let module = Path::new("src/daemon/mod.rs");
    assert!(imported_files(module, &code_only("pub use journal::Journal; use self::scan::X;")).is_empty());
    let a = PathBuf::from("a.rs");
    let b = PathBuf::from("b.rs");
    let c = PathBuf::from("c.rs");
    let edges: BTreeMap<PathBuf, BTreeSet<PathBuf>> = [
        (a.clone(), [b.clone()].into()),
        (b.clone(), [c.clone()].into()),
        (c.clone(), [a.clone()].into()),
        (PathBuf::from("d.rs"), [a.clone()].into()),
    ]
    .into();
    assert_eq!(circles(&edges), vec![vec![a, b, c]]);
}
