//! Proves: `udev/99-s3tir.rules` parses as udev rule syntax (every token is KEY[{attr}] OP
//! "value" with an operator udev knows, continuation lines joined), and it has rules matching
//! the PureThermal (1e4e:0100) video node, the FLIR Boson (09cb:4007) video node and the Boson's
//! tty, each giving a stable `s3tir/` symlink and group access with mode 0660 (never
//! world-accessible). Does NOT run udev (no `udevadm` on CI machines, no devices): whether a
//! real device matches is checked on the rig with the steps in udev/README.md.
#![allow(clippy::unwrap_used)]

use std::collections::BTreeMap;

#[derive(Debug)]
struct Token {
    key: String,
    op: String,
    value: String,
}

fn parse_token(t: &str) -> Result<Token, String> {
    let ops = ["==", "!=", "+=", "-=", ":=", "="];
    let (pos, op) = ops
        .iter()
        .filter_map(|op| t.find(op).map(|p| (p, *op)))
        .min_by_key(|(p, op)| (*p, std::cmp::Reverse(op.len())))
        .ok_or_else(|| format!("no operator in {t:?}"))?;
    let key = t[..pos].trim();
    let value = t[pos + op.len()..].trim();
    let key_ok = {
        let (name, attr) = match key.split_once('{') {
            Some((n, rest)) => (n, Some(rest)),
            None => (key, None),
        };
        !name.is_empty()
            && name.chars().all(|c| c.is_ascii_uppercase() || c == '_')
            && attr.is_none_or(|a| a.ends_with('}') && a.len() > 1)
    };
    if !key_ok {
        return Err(format!("bad key {key:?} in {t:?}"));
    }
    if !(value.len() >= 2 && value.starts_with('"') && value.ends_with('"')) {
        return Err(format!("value not quoted in {t:?}"));
    }
    Ok(Token {
        key: key.to_owned(),
        op: op.to_owned(),
        value: value[1..value.len() - 1].to_owned(),
    })
}

/// Rules as token lists, continuation lines joined, comments dropped.
fn parse_rules(text: &str) -> Result<Vec<Vec<Token>>, String> {
    let mut rules = Vec::new();
    let mut line = String::new();
    for raw in text.lines() {
        let t = raw.trim();
        if line.is_empty() && (t.is_empty() || t.starts_with('#')) {
            continue;
        }
        if let Some(head) = t.strip_suffix('\\') {
            line.push_str(head);
            line.push(' ');
            continue;
        }
        line.push_str(t);
        let tokens = line
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(parse_token)
            .collect::<Result<Vec<_>, _>>()?;
        rules.push(tokens);
        line.clear();
    }
    if !line.is_empty() {
        return Err("file ends inside a continued line".into());
    }
    Ok(rules)
}

fn matches(rule: &[Token]) -> BTreeMap<String, String> {
    rule.iter()
        .filter(|t| t.op == "==")
        .map(|t| (t.key.clone(), t.value.clone()))
        .collect()
}

fn assigns(rule: &[Token], key: &str) -> Option<String> {
    rule.iter()
        .find(|t| t.key == key && t.op != "==" && t.op != "!=")
        .map(|t| t.value.clone())
}

#[test]
fn rules_parse_and_cover_lepton_boson_video_and_tty() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../udev/99-s3tir.rules");
    let text = std::fs::read_to_string(path).unwrap();
    let rules = parse_rules(&text).unwrap_or_else(|e| panic!("{path}: {e}"));
    let want = [
        ("video4linux", "1e4e", "0100", "video", "s3tir/lepton"),
        ("video4linux", "09cb", "4007", "video", "s3tir/boson"),
        ("tty", "09cb", "4007", "dialout", "s3tir/boson-serial"),
    ];
    for (subsystem, vendor, product, group, link) in want {
        let found = rules.iter().find(|r| {
            let m = matches(r);
            m.get("SUBSYSTEM").map(String::as_str) == Some(subsystem)
                && m.get("ATTRS{idVendor}").map(String::as_str) == Some(vendor)
                && m.get("ATTRS{idProduct}").map(String::as_str) == Some(product)
        });
        let rule =
            found.unwrap_or_else(|| panic!("no rule matches {subsystem} {vendor}:{product}"));
        assert_eq!(
            assigns(rule, "GROUP").as_deref(),
            Some(group),
            "{subsystem} {vendor}:{product}"
        );
        let mode = assigns(rule, "MODE").unwrap();
        let bits = u32::from_str_radix(&mode, 8).unwrap();
        assert_eq!(
            bits & 0o007,
            0,
            "{vendor}:{product}: mode {mode} is world-accessible"
        );
        assert_eq!(
            bits & 0o060,
            0o060,
            "{vendor}:{product}: group needs rw, mode {mode}"
        );
        assert_eq!(assigns(rule, "SYMLINK").as_deref(), Some(link));
    }
}

#[test]
fn the_parser_rejects_broken_rules() {
    assert!(
        parse_rules("SUBSYSTEM==\"tty\", GROUP=dialout\n").is_err(),
        "unquoted value"
    );
    assert!(
        parse_rules("subsystem==\"tty\"\n").is_err(),
        "lower-case key"
    );
    assert!(
        parse_rules("SUBSYSTEM==\"tty\", \\\n").is_err(),
        "dangling continuation"
    );
    assert_eq!(
        parse_rules("# c\nKERNEL==\"ttyACM*\", MODE=\"0660\"\n")
            .unwrap()
            .len(),
        1
    );
}
