//! The few HTML pieces the report is built from. Every text goes through [`esc`]: names of files, jobs and
//! scans, error messages and every other string from an input or a client are data, never markup.

use std::fmt::Write as _;

/// `text` escaped for HTML element content and double-quoted attribute values: `&`, `<`, `>`, `"` and `'`
/// become entities, and control characters other than tab and newline are dropped.
pub fn esc(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 8);
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            '\t' | '\n' => out.push(c),
            c if c.is_control() => {}
            c => out.push(c),
        }
    }
    out
}

/// A JSON value as a table cell's text: a string unquoted, a number as JSON writes it (the shortest form
/// that reads back to the same double), `null` as an en dash; escaped.
pub fn cell(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::String(s) => esc(s),
        serde_json::Value::Null => "&#8211;".into(),
        other => esc(&other.to_string()),
    }
}

/// A table: `head` cells, then `rows` (each cell already HTML), inside a scrolling wrapper so that a wide
/// table does not widen the page on a phone. `id` names it for tests and links.
pub fn table(id: &str, head: &[&str], rows: &[Vec<String>]) -> String {
    let mut s = format!("<div class=\"scroll\"><table id=\"{}\"><thead><tr>", esc(id));
    for h in head {
        let _ = write!(s, "<th>{}</th>", esc(h));
    }
    s.push_str("</tr></thead><tbody>");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            let _ = write!(s, "<td>{c}</td>");
        }
        s.push_str("</tr>");
    }
    s.push_str("</tbody></table></div>");
    s
}

/// A definition list of (term, HTML value) pairs.
pub fn facts<K: AsRef<str>>(pairs: &[(K, String)]) -> String {
    let mut s = String::from("<dl class=\"facts\">");
    for (k, v) in pairs {
        let _ = write!(s, "<dt>{}</dt><dd>{v}</dd>", esc(k.as_ref()));
    }
    s.push_str("</dl>");
    s
}

/// A section with a heading.
pub fn section(id: &str, title: &str, body: &str) -> String {
    format!("<section id=\"{}\"><h2>{}</h2>{body}</section>", esc(id), esc(title))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markup_in_a_name_is_text() {
        let name = "<img src=x onerror=alert(1)>.ply";
        assert_eq!(esc(name), "&lt;img src=x onerror=alert(1)&gt;.ply");
        assert_eq!(esc("a\"b'c&d"), "a&quot;b&#39;c&amp;d");
        assert_eq!(esc("bell\u{7}\u{1b}[31m"), "bell[31m");
        assert_eq!(cell(&serde_json::json!("<b>")), "&lt;b&gt;");
        assert_eq!(cell(&serde_json::json!(0.1)), "0.1");
        let t = table("t", &["<x>"], &[vec![esc("</td><script>")]]);
        assert!(!t.contains("<script>") && !t.contains("<x>"), "{t}");
    }
}
