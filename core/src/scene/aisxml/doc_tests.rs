//! docs/aisxml.md and docs/aisxml-extensions.md checked against the
//! elements' attribute tables (`super::ELEMENTS`): every attribute
//! a table holds is documented (an extension in the extensions document),
//! and every attribute the documents show is in a table.
//!
//! "Shown" means written where a reader looks for it: inside a tag of the
//! element (`<light type="spot" ...>` in an example, or a signature such as
//! `<camera id position (direction | lookat) [up] fov>`), or in the first
//! column of a table under a heading that names the element (`<render>`).

use super::table::Attribute;
use super::ELEMENTS;
use std::collections::{BTreeMap, BTreeSet};

type Shown = BTreeMap<&'static str, BTreeSet<String>>;

/// The elements that take attributes, each with its table.
fn attribute_tables() -> impl Iterator<Item = (&'static str, &'static [Attribute])> {
    ELEMENTS
        .iter()
        .filter(|e| !e.attributes.is_empty())
        .map(|e| (e.name, e.attributes))
}

fn read_doc(name: &str) -> String {
    let path = format!("{}/../docs/{name}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

fn is_name_char(c: char) -> bool {
    c.is_ascii_lowercase() || c == '-'
}

/// The attribute names inside tags `<element ...>` of `text`, per element.
fn in_tags(text: &str, shown: &mut Shown) {
    for (element, _) in attribute_tables() {
        let open = format!("<{element}");
        let mut rest = text;
        while let Some(i) = rest.find(&open) {
            let after = &rest[i + open.len()..];
            rest = after;
            // `<scene` must not match `<scenes`, nor `<model` `<models`.
            if !after.starts_with(|c: char| c.is_whitespace() || c == '>' || c == '/') {
                continue;
            }
            let Some(end) = after.find('>') else { break };
            // Drop quoted values, keep the names.
            let mut names = String::new();
            let mut quoted = false;
            for c in after[..end].chars() {
                if c == '"' {
                    quoted = !quoted;
                    names.push(' ');
                } else if !quoted {
                    names.push(c);
                }
            }
            for word in names.split(|c: char| !is_name_char(c)) {
                if !word.is_empty() {
                    shown.entry(element).or_default().insert(word.to_string());
                }
            }
        }
    }
}

/// The backquoted names in the first column of each table whose heading
/// names one element (`<render>`), for that element.
fn in_tables(text: &str, shown: &mut Shown) {
    let mut element: Option<&'static str> = None;
    let mut rows = 0;
    for line in text.lines() {
        if line.starts_with('#') {
            element = attribute_tables()
                .map(|(e, _)| e)
                .find(|e| line.contains(&format!("`<{e}>`")) || line.contains(&format!("`<{e} ")));
            rows = 0;
            continue;
        }
        if !line.starts_with('|') {
            rows = 0;
            continue;
        }
        rows += 1;
        // The first two rows are the header and its rule.
        let Some(e) = element.filter(|_| rows > 2) else {
            continue;
        };
        let first = line.split('|').nth(1).unwrap_or("");
        for (i, part) in first.split('`').enumerate() {
            if i % 2 == 1 && !part.is_empty() && part.chars().all(is_name_char) {
                shown.entry(e).or_default().insert(part.to_string());
            }
        }
    }
}

fn shown_in(doc: &str) -> Shown {
    let text = read_doc(doc);
    let mut shown = Shown::new();
    in_tags(&text, &mut shown);
    in_tables(&text, &mut shown);
    shown
}

#[test]
fn the_attribute_tables_and_the_format_reference_agree() {
    let core = shown_in("aisxml.md");
    let ext = shown_in("aisxml-extensions.md");
    let mut problems = Vec::new();
    for (element, table) in attribute_tables() {
        for &Attribute {
            name, extension, ..
        } in table
        {
            let (doc, shown) = if extension {
                ("docs/aisxml-extensions.md", &ext)
            } else {
                ("docs/aisxml.md", &core)
            };
            if !shown.get(element).is_some_and(|s| s.contains(name)) {
                problems.push(format!(
                    "<{element}> {name}: in the table, not shown in {doc}"
                ));
            }
        }
        let documented = core
            .get(element)
            .into_iter()
            .chain(ext.get(element))
            .flatten();
        for name in documented {
            if !table.iter().any(|a| a.name == name) {
                problems.push(format!(
                    "<{element}> {name}: documented, but not in the element's table"
                ));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    // The check sees the documents at all.
    assert!(core["render"].contains("ao-distance"));
    assert!(core["camera"].contains("lookat"));
    assert!(ext["render"].contains("noise-threshold"));
}

#[test]
fn the_tables_name_each_attribute_once_with_a_meaning() {
    for (element, table) in attribute_tables() {
        let mut seen = BTreeSet::new();
        for a in table {
            assert!(seen.insert(a.name), "<{element}> lists {} twice", a.name);
            assert!(
                !a.ty.is_empty() && !a.default.is_empty() && !a.meaning.is_empty(),
                "<{element}> {}: type, default and meaning are all required",
                a.name
            );
        }
    }
}

#[test]
fn the_check_reads_tags_signatures_and_tables() {
    let text =
        "### `<render>`\n| attribute | default |\n|---|---|\n| `width`, `height` | required |\n\n\
                `<camera id position (direction | lookat) [up]>` and \
                <light type=\"spot\" position=\"0 1 0\"/> but not <lights x=\"1\">\n";
    let mut shown = Shown::new();
    in_tags(text, &mut shown);
    in_tables(text, &mut shown);
    let names = |e: &str| shown[e].iter().map(String::as_str).collect::<Vec<_>>();
    assert_eq!(names("render"), ["height", "width"]);
    assert_eq!(
        names("camera"),
        ["direction", "id", "lookat", "position", "up"]
    );
    assert_eq!(names("light"), ["position", "type"]);
}

#[test]
fn the_element_table_names_each_element_once_and_every_child() {
    let mut seen = BTreeSet::new();
    for e in ELEMENTS {
        assert!(seen.insert(e.name), "<{}> has two rows", e.name);
        assert!(
            !e.text || e.children.is_empty(),
            "<{}> takes text and elements",
            e.name
        );
    }
    for e in ELEMENTS {
        for c in e.children {
            assert!(
                seen.contains(c),
                "<{}> holds <{c}>, which has no row",
                e.name
            );
        }
    }
    // Every element but the root is inside another, and only the root's
    // children are read by the root.
    let (root, rest) = ELEMENTS.split_first().expect("a root");
    for e in rest {
        assert!(
            ELEMENTS.iter().any(|p| p.children.contains(&e.name)),
            "<{}> is inside no element",
            e.name
        );
        assert_eq!(
            e.read.is_some(),
            root.children.contains(&e.name),
            "<{}>: read by the root exactly when its child",
            e.name
        );
    }
}
