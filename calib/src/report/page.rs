//! A report page written once and rendered twice: as Markdown (`report.md`, for diffs and
//! terminals) and as one self-contained HTML page (`report.html`: figures embedded as `data:`
//! URIs, each also linked to its file beside the page; no external URL). The content is a list
//! of [`Block`]s — headings, paragraphs, tables, lists, figures — so the two files cannot drift
//! apart: a table added to a report appears in both.
//!
//! Text is plain: the renderers escape it (HTML) or leave it as it is (Markdown, where a cell's
//! `|` is escaped). A [`Cell`] marked `code` is shown as code in both.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One table cell: its text, and whether it is code (a file name, an identifier).
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    pub text: String,
    pub code: bool,
}

impl Cell {
    pub fn code(text: impl Into<String>) -> Self {
        Self {
            text: text.into(),
            code: true,
        }
    }
}

impl<T: Into<String>> From<T> for Cell {
    fn from(text: T) -> Self {
        Self {
            text: text.into(),
            code: false,
        }
    }
}

/// A column's heading and alignment (numbers right, words left).
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    pub title: String,
    pub left: bool,
}

impl Column {
    /// A left-aligned column (names, reasons).
    pub fn text(title: &str) -> Self {
        Self {
            title: title.to_string(),
            left: true,
        }
    }
    /// A right-aligned column (figures).
    pub fn number(title: &str) -> Self {
        Self {
            title: title.to_string(),
            left: false,
        }
    }
}

/// One piece of a page.
#[derive(Debug, Clone, PartialEq)]
pub enum Block {
    /// A section heading; `id` is its HTML anchor.
    Heading {
        text: String,
        id: String,
    },
    Paragraph(String),
    /// A bulleted list; an empty list renders as "None.".
    List {
        items: Vec<String>,
        warn: bool,
    },
    /// A table; no rows renders as "None.".
    Table {
        columns: Vec<Column>,
        rows: Vec<Vec<Cell>>,
    },
    /// A figure: a PNG file beside the page (relative name) and its caption.
    Figure {
        file: String,
        caption: String,
    },
}

impl Block {
    pub fn heading(text: impl Into<String>, id: impl Into<String>) -> Self {
        Self::Heading {
            text: text.into(),
            id: id.into(),
        }
    }
    pub fn paragraph(text: impl Into<String>) -> Self {
        Self::Paragraph(text.into())
    }
}

/// A page: its title and blocks.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Page {
    pub title: String,
    pub blocks: Vec<Block>,
}

/// A figure file that could not be read back for embedding.
#[derive(Debug, thiserror::Error)]
#[error("cannot read figure {path} back to embed it in the HTML page")]
pub struct FigureError {
    pub path: PathBuf,
    #[source]
    pub source: std::io::Error,
}

impl Page {
    pub fn new(title: &str) -> Self {
        Self {
            title: title.to_string(),
            blocks: Vec::new(),
        }
    }

    pub fn push(&mut self, block: Block) {
        self.blocks.push(block);
    }

    /// The page as Markdown.
    pub fn markdown(&self) -> String {
        let mut md = format!("# {}\n\n", self.title);
        for block in &self.blocks {
            match block {
                Block::Heading { text, .. } => {
                    let _ = writeln!(md, "## {text}\n");
                }
                Block::Paragraph(text) => {
                    let _ = writeln!(md, "{text}\n");
                }
                Block::List { items, .. } => {
                    if items.is_empty() {
                        md.push_str("None.\n");
                    }
                    for item in items {
                        let _ = writeln!(md, "- {item}");
                    }
                    md.push('\n');
                }
                Block::Table { columns, rows } => markdown_table(&mut md, columns, rows),
                Block::Figure { file, caption } => {
                    let _ = writeln!(md, "![{caption}]({file})\n");
                }
            }
        }
        md
    }

    /// The page as one self-contained HTML document; figures are read from `dir` and embedded.
    pub fn html(&self, dir: &Path) -> Result<String, FigureError> {
        let mut h = String::new();
        let _ = writeln!(
            h,
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n<title>{t}</title>\n<style>\n{STYLE}</style>\n</head>\n<body>\n<h1>{t}</h1>",
            t = esc(&self.title)
        );
        for block in &self.blocks {
            match block {
                Block::Heading { text, id } => {
                    let _ = writeln!(h, "<h2 id=\"{}\">{}</h2>", esc(id), esc(text));
                }
                Block::Paragraph(text) => {
                    let _ = writeln!(h, "<p>{}</p>", esc(text));
                }
                Block::List { items, warn } => {
                    if items.is_empty() {
                        h.push_str("<p>None.</p>\n");
                        continue;
                    }
                    let class = if *warn { " class=\"warn\"" } else { "" };
                    h.push_str("<ul>\n");
                    for item in items {
                        let _ = writeln!(h, "<li{class}>{}</li>", esc(item));
                    }
                    h.push_str("</ul>\n");
                }
                Block::Table { columns, rows } => html_table(&mut h, columns, rows),
                Block::Figure { file, caption } => {
                    let path = dir.join(file);
                    let bytes = std::fs::read(&path).map_err(|source| FigureError {
                        path: path.clone(),
                        source,
                    })?;
                    let _ = writeln!(
                        h,
                        "<figure><a href=\"{f}\"><img alt=\"{c}\" src=\"data:image/png;base64,{b}\"></a><figcaption>{c} (<a href=\"{f}\">{f}</a>)</figcaption></figure>",
                        f = esc(file),
                        c = esc(caption),
                        b = base64(&bytes)
                    );
                }
            }
        }
        h.push_str("</body>\n</html>\n");
        Ok(h)
    }
}

/// The page's style sheet: readable on a phone (tables scroll sideways, images shrink).
const STYLE: &str =
    "body { font-family: sans-serif; max-width: 1000px; margin: 2em auto; padding: 0 1em; }
.scroll { overflow-x: auto; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: right; }
th { background: #eee; }
td.l, th.l { text-align: left; }
figure { margin: 1em 0; }
img { max-width: 100%; border: 1px solid #ddd; }
.warn { color: #a40; }
";

fn markdown_table(md: &mut String, columns: &[Column], rows: &[Vec<Cell>]) {
    if rows.is_empty() {
        md.push_str("None.\n\n");
        return;
    }
    let cell = |c: &Cell| {
        let text = c.text.replace('|', "\\|");
        if c.code { format!("`{text}`") } else { text }
    };
    let titles: Vec<&str> = columns.iter().map(|c| c.title.as_str()).collect();
    let rules: Vec<&str> = columns
        .iter()
        .map(|c| if c.left { "---" } else { "--:" })
        .collect();
    let _ = writeln!(md, "| {} |\n|{}|", titles.join(" | "), rules.join("|"));
    for row in rows {
        let cells: Vec<String> = row.iter().map(cell).collect();
        let _ = writeln!(md, "| {} |", cells.join(" | "));
    }
    md.push('\n');
}

fn html_table(h: &mut String, columns: &[Column], rows: &[Vec<Cell>]) {
    if rows.is_empty() {
        h.push_str("<p>None.</p>\n");
        return;
    }
    let class = |left: bool| if left { " class=\"l\"" } else { "" };
    h.push_str("<div class=\"scroll\"><table>\n<tr>");
    for c in columns {
        let _ = write!(h, "<th{}>{}</th>", class(c.left), esc(&c.title));
    }
    h.push_str("</tr>\n");
    for row in rows {
        h.push_str("<tr>");
        for (k, cell) in row.iter().enumerate() {
            let left = columns.get(k).is_some_and(|c| c.left);
            let text = esc(&cell.text);
            if cell.code {
                let _ = write!(h, "<td{}><code>{text}</code></td>", class(left));
            } else {
                let _ = write!(h, "<td{}>{text}</td>", class(left));
            }
        }
        h.push_str("</tr>\n");
    }
    h.push_str("</table></div>\n");
}

/// Escapes text for HTML element content and attribute values.
pub fn esc(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for ch in text.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Standard base64 (RFC 4648, with padding), for `data:` URIs.
pub fn base64(bytes: &[u8]) -> String {
    const TABLE: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(char::from(TABLE[((n >> (18 - 6 * k)) & 63) as usize]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn base64_matches_rfc_4648_vectors() {
        for (input, want) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(input.as_bytes()), want, "base64({input:?})");
        }
    }

    #[test]
    fn html_escaping_covers_markup_characters() {
        assert_eq!(
            esc(r#"<a href="x">'&'</a>"#),
            "&lt;a href=&quot;x&quot;&gt;&#39;&amp;&#39;&lt;/a&gt;"
        );
    }

    /// One page, both renderings: every heading, cell and list item in each, escaped for its
    /// format; empty tables and lists say "None."; a missing figure names its file.
    #[test]
    fn both_renderings_carry_the_same_content() {
        let mut page = Page::new("A <report>");
        page.push(Block::heading("Result", "result"));
        page.push(Block::Table {
            columns: vec![Column::text("camera"), Column::number("RMS px")],
            rows: vec![vec![Cell::code("a|b"), "0.123".into()]],
        });
        page.push(Block::heading("Warnings", "warnings"));
        page.push(Block::List {
            items: vec![],
            warn: true,
        });
        page.push(Block::Table {
            columns: vec![Column::text("file")],
            rows: vec![],
        });
        let md = page.markdown();
        assert!(md.starts_with("# A <report>\n"), "{md}");
        assert!(
            md.contains("| camera | RMS px |\n|---|--:|\n| `a\\|b` | 0.123 |"),
            "{md}"
        );
        assert_eq!(md.matches("None.").count(), 2, "{md}");
        let dir = std::env::temp_dir();
        let html = page.html(&dir).unwrap();
        assert!(html.contains("<h1>A &lt;report&gt;</h1>"), "{html}");
        assert!(html.contains("<h2 id=\"result\">Result</h2>"), "{html}");
        assert!(
            html.contains("<td class=\"l\"><code>a|b</code></td><td>0.123</td>"),
            "{html}"
        );
        assert_eq!(html.matches("<p>None.</p>").count(), 2, "{html}");
        page.push(Block::Figure {
            file: "no-such-figure.png".into(),
            caption: "x".into(),
        });
        let err = page.html(Path::new("/nonexistent-dir")).unwrap_err();
        assert!(
            err.path.ends_with("no-such-figure.png"),
            "the error names the figure: {err}"
        );
    }
}
