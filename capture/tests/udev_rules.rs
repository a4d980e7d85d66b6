//! Proves: `udev/99-s3tir.rules` parses as udev rule syntax (every token is KEY[{attr}] OP
//! "value" with an operator udev knows, continuation lines joined), and it has rules matching
//! the PureThermal (1e4e:0100) video node, the FLIR Boson (09cb:4007) video node and the Boson's
//! tty, each giving a stable `s3tir/` symlink and group access with mode 0660 (never
//! world-accessible); that the rules and `capture/systemd/s3tir-capture@.service` agree: every
//! thermal core's video rule tags it for systemd and wants `s3tir-capture@<link name>.service`,
//! the unit is a template ordered after `dev-s3tir-%i.device` (the device unit systemd derives
//! from the `s3tir/<name>` link), records `/dev/s3tir/%i` with the serial and RGB links the
//! rules create, writes with `UMask=0027`, and is wanted by that device unit. Does NOT run
//! udev or systemd (no `udevadm`/`systemd-analyze` on CI machines, no devices): whether a real
//! device matches is checked on the rig with the steps in udev/README.md.
#![allow(clippy::unwrap_used, clippy::expect_used)]

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

fn all_assigns(rule: &[Token], key: &str) -> Vec<String> {
    rule.iter()
        .filter(|t| t.key == key && t.op != "==" && t.op != "!=")
        .map(|t| t.value.clone())
        .collect()
}

/// `[Section]` → key → values (repeated keys kept in order), continuation lines joined.
fn parse_unit(text: &str) -> BTreeMap<String, BTreeMap<String, Vec<String>>> {
    let mut out: BTreeMap<String, BTreeMap<String, Vec<String>>> = BTreeMap::new();
    let mut section = String::new();
    let mut line = String::new();
    for raw in text.lines() {
        let t = raw.trim();
        if line.is_empty() && (t.is_empty() || t.starts_with('#')) {
            continue;
        }
        if let Some(cont) = t.strip_suffix('\\') {
            line.push_str(cont);
            line.push(' ');
            continue;
        }
        line.push_str(t);
        if line.starts_with('[') {
            section = line.trim_matches(['[', ']']).to_string();
        } else {
            let (k, v) = line.split_once('=').expect("key=value line in the unit");
            out.entry(section.clone())
                .or_default()
                .entry(k.trim().to_string())
                .or_default()
                .push(v.trim().to_string());
        }
        line.clear();
    }
    out
}

#[test]
fn rules_and_unit_agree_on_names_tags_and_permissions() {
    let rules_path = concat!(env!("CARGO_MANIFEST_DIR"), "/../udev/99-s3tir.rules");
    let unit_path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/systemd/s3tir-capture@.service"
    );
    let rules = parse_rules(&std::fs::read_to_string(rules_path).unwrap()).unwrap();
    let unit = parse_unit(&std::fs::read_to_string(unit_path).unwrap());
    let get = |section: &str, key: &str| -> Vec<String> {
        unit.get(section)
            .and_then(|s| s.get(key))
            .cloned()
            .unwrap_or_default()
    };
    let unit_name = "s3tir-capture@.service";
    // The unit's view of its instance: the device it waits for and the nodes it opens.
    assert!(
        get("Unit", "After")
            .iter()
            .any(|v| v.split_whitespace().any(|u| u == "dev-s3tir-%i.device")),
        "{unit_name}: must be ordered after dev-s3tir-%i.device"
    );
    assert_eq!(
        get("Install", "WantedBy"),
        ["dev-s3tir-%i.device"],
        "{unit_name}: enabled instances are wanted by their core's device unit"
    );
    assert_eq!(
        get("Service", "UMask"),
        ["0027"],
        "{unit_name}: sessions must not be world-readable"
    );
    let exec = get("Service", "ExecStart").join(" ");
    for node in [
        "--device /dev/s3tir/%i",
        "/dev/s3tir/%i-serial",
        "/dev/s3tir/rgb",
    ] {
        assert!(
            exec.contains(node),
            "{unit_name}: ExecStart must use {node}: {exec}"
        );
    }
    assert!(
        !exec.contains("/dev/video"),
        "{unit_name}: no unstable /dev/videoN names: {exec}"
    );

    // Every thermal core's video rule: the systemd tag and the instance it starts.
    let mut cores = Vec::new();
    for rule in &rules {
        let m = matches(rule);
        let Some(link) = assigns(rule, "SYMLINK") else {
            continue;
        };
        let name = link
            .strip_prefix("s3tir/")
            .expect("links live under /dev/s3tir/");
        let tags = all_assigns(rule, "TAG");
        if m.get("SUBSYSTEM").map(String::as_str) == Some("video4linux") {
            assert!(
                tags.iter().any(|t| t == "systemd"),
                "{link}: TAG+=\"systemd\" is needed for dev-s3tir-{name}.device to exist"
            );
            assert_eq!(
                all_assigns(rule, "ENV{SYSTEMD_WANTS}"),
                [format!("s3tir-capture@{name}.service")],
                "{link}: must start the unit's instance for this core"
            );
            cores.push(name.to_string());
        }
        if name.ends_with("-serial") {
            let core = name.trim_end_matches("-serial");
            assert!(
                rules.iter().any(|r| assigns(r, "SYMLINK").as_deref() == Some(&format!("s3tir/{core}")[..])),
                "{link}: the unit looks for /dev/s3tir/%i-serial, so {core} must be a core's link"
            );
        }
    }
    assert_eq!(cores, ["lepton", "boson"], "the cores the unit serves");
    // The RGB rule is a template the user fills in; the unit records it only if the link exists.
    let rules_text = std::fs::read_to_string(rules_path).unwrap();
    assert!(
        rules_text.contains("SYMLINK+=\"s3tir/rgb\""),
        "the rules file documents the s3tir/rgb link the unit records"
    );
}

/// systemd's own check of the unit (an instance of the template), where `systemd-analyze`
/// exists (Debian images have it; it needs no running systemd).
#[test]
fn systemd_analyze_verifies_the_unit() {
    let unit = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/systemd/s3tir-capture@.service"
    );
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(unit, dir.path().join("s3tir-capture@.service")).unwrap();
    let out = match std::process::Command::new("systemd-analyze")
        .args(["verify", "--man=no", "./s3tir-capture@boson.service"])
        .current_dir(dir.path())
        .output()
    {
        Ok(o) => o,
        Err(e) => {
            s3tir_capture::skip::skip("systemd-analyze", &format!("no systemd-analyze ({e})"));
            return;
        }
    };
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && stderr.trim().is_empty(),
        "systemd-analyze verify s3tir-capture@boson.service: {} {stderr}",
        out.status
    );
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
