//! Dotted-key overrides of a scenario file (`smlworld run --set KEY=VALUE`, the Python package's
//! `overrides=`): set values in the TOML table before it is parsed and checked like the file.
//!
//! A key is a dotted path: `seed`, `v2v.wifi.loss`, `vehicles.0.speed` (element 0 of the array
//! `vehicles`), `vehicles.*.lane_change.politeness` (every element). Tables missing on the way are
//! created, so the strict parser then rejects a misspelt key exactly as it rejects a typo in the
//! file. A key that goes through an array without an index or `*` (`vehicles.controller.platoon.
//! time_gap`) sets the value in every element that already has the tables on the way (and only
//! there), as the Python overrides always did.

use std::path::Path as FsPath;

use crate::sim::ControllerRegistry;

use super::{Scenario, ScenarioError};

/// One `KEY=VALUE` of `--set`: the value is parsed as TOML (`0.5`, `true`, `"car"`,
/// `{ type = "idm" }`, `[1, 2]`); a bare word that is not TOML (`car`) is taken as a string.
pub fn parse_override(text: &str) -> Result<(String, toml::Value), String> {
    let Some((key, value)) = text.split_once('=') else {
        return Err(format!("`{text}`: expected KEY=VALUE, e.g. `vehicles.*.speed=12.5` or `seed=3`"));
    };
    let (key, value) = (key.trim(), value.trim());
    check_key(key)?;
    let parsed = toml::from_str::<toml::Table>(&format!("v = {value}")).ok().and_then(|mut t| t.remove("v"));
    match parsed {
        Some(v) => Ok((key.to_string(), v)),
        None if !value.is_empty() && !value.contains(['"', '\'', '[', ']', '{', '}', '=']) => {
            Ok((key.to_string(), toml::Value::String(value.to_string())))
        }
        None => Err(format!(
            "`{text}`: the value `{value}` is not TOML (quote strings: KEY='\"text\"', arrays [1, 2], tables {{ a = 1 }})"
        )),
    }
}

fn check_key(key: &str) -> Result<(), String> {
    if key.split('.').any(|p| p.trim().is_empty()) {
        return Err(format!(
            "override `{key}`: keys are dotted names like `seed`, `vehicles.0.speed` or `vehicles.*.speed`"
        ));
    }
    Ok(())
}

/// The TOML type of `v` in words (for messages).
fn kind(v: &toml::Value) -> &'static str {
    match v {
        toml::Value::String(_) => "a string",
        toml::Value::Integer(_) => "an integer",
        toml::Value::Float(_) => "a float",
        toml::Value::Boolean(_) => "a boolean",
        toml::Value::Datetime(_) => "a date",
        toml::Value::Array(_) => "an array",
        toml::Value::Table(_) => "a table",
    }
}

/// Set `key` (dotted, see the module docs) to `value` in a scenario table. Errors name the key
/// and what is on the way instead of a table or array.
pub fn apply_override(table: &mut toml::Table, key: &str, value: toml::Value) -> Result<(), String> {
    check_key(key)?;
    let parts: Vec<&str> = key.split('.').map(str::trim).collect();
    let mut done = 0;
    set_in(table, &parts, &value, &mut Vec::new(), true, &mut done).map_err(|m| format!("override `{key}`: {m}"))?;
    if done == 0 {
        let on_the_way = parts[..parts.len() - 1].join(".");
        return Err(format!("override `{key}`: no element of the scenario has the table `{on_the_way}`"));
    }
    Ok(())
}

/// Set `parts` below table `t` (whose own path is `at`). `create`: tables missing on the way are
/// made (false inside an array walked without index or `*`). Counts the values set in `done`.
fn set_in(
    t: &mut toml::Table,
    parts: &[&str],
    value: &toml::Value,
    at: &mut Vec<String>,
    create: bool,
    done: &mut usize,
) -> Result<(), String> {
    let (first, rest) = match parts {
        [] => return Ok(()),
        [last] => {
            t.insert((*last).to_string(), value.clone());
            *done += 1;
            return Ok(());
        }
        [first, rest @ ..] => (*first, rest),
    };
    if !t.contains_key(first) {
        if !create {
            return Ok(());
        }
        if rest[0] == "*" {
            at.push(first.to_string());
            return Err(format!("the scenario has no array `{}` to go through with `{}`", at.join("."), rest[0]));
        }
        t.insert(first.to_string(), toml::Value::Table(toml::Table::new()));
    }
    at.push(first.to_string());
    let item = t.get_mut(first).expect("inserted above");
    let r = set_item(item, rest, value, at, create, done);
    at.pop();
    r
}

/// Set `parts` below the value `item` at path `at`.
fn set_item(
    item: &mut toml::Value,
    parts: &[&str],
    value: &toml::Value,
    at: &mut Vec<String>,
    create: bool,
    done: &mut usize,
) -> Result<(), String> {
    match item {
        toml::Value::Table(t) => {
            if parts[0] == "*" {
                return Err(format!("`{}` is a table, not an array: `*` goes through arrays only", at.join(".")));
            }
            set_in(t, parts, value, at, create, done)
        }
        toml::Value::Array(a) => {
            let (picked, rest): (Vec<usize>, &[&str]) = if parts[0] == "*" {
                ((0..a.len()).collect(), &parts[1..])
            } else if let Ok(i) = parts[0].parse::<usize>() {
                if i >= a.len() {
                    return Err(format!(
                        "`{}` has {} elements (indices 0..{}), not {i}",
                        at.join("."),
                        a.len(),
                        a.len().saturating_sub(1)
                    ));
                }
                (vec![i], &parts[1..])
            } else {
                // No index: every element that has the tables on the way (nothing is created).
                for (i, e) in a.iter_mut().enumerate() {
                    at.push(i.to_string());
                    if let toml::Value::Table(t) = e {
                        set_in(t, parts, value, at, false, done)?;
                    }
                    at.pop();
                }
                return Ok(());
            };
            // An element picked by index or `*`: create what is missing below it.
            for i in picked {
                at.push(i.to_string());
                let e = &mut a[i];
                if rest.is_empty() {
                    *e = value.clone();
                    *done += 1;
                } else {
                    set_item(e, rest, value, at, true, done)?;
                }
                at.pop();
            }
            Ok(())
        }
        other if create => Err(format!("`{}` is {}, not a table", at.join("."), kind(other))),
        _ => Ok(()),
    }
}

/// The scenario text of `path`: the file, or for a SUMO configuration the scenario it describes.
fn scenario_text(path: &FsPath) -> Result<String, ScenarioError> {
    let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Io { path: path.into(), source })?;
    if path.extension().is_some_and(|e| e == "sumocfg") { super::sumocfg::scenario_text(&text, path) } else { Ok(text) }
}

/// Read the scenario file `path`, apply `seed` (replaces `seed`) and `overrides` in order, and
/// parse and check the result like the file (with the controllers of `controllers`). Errors name
/// the file and the key.
pub fn load_with_overrides(
    path: &FsPath,
    seed: Option<u64>,
    overrides: &[(String, toml::Value)],
    controllers: &ControllerRegistry,
) -> Result<Scenario, ScenarioError> {
    let text = scenario_text(path)?;
    if seed.is_none() && overrides.is_empty() {
        return Scenario::parse_str_with(&text, path, controllers);
    }
    let mut table: toml::Table =
        toml::from_str(&text).map_err(|e| ScenarioError::Syntax { path: path.into(), message: e.to_string() })?;
    for (key, value) in overrides {
        apply_override(&mut table, key, value.clone()).map_err(|problem| ScenarioError::Invalid {
            path: path.into(),
            key: format!("--set {key}"),
            problem: problem.trim_start_matches(&format!("override `{key}`: ")).to_string(),
        })?;
    }
    if let Some(seed) = seed {
        let seed = i64::try_from(seed).map_err(|_| ScenarioError::Invalid {
            path: path.into(),
            key: "--seed".into(),
            problem: format!("must be < 2^63, got {seed}"),
        })?;
        table.insert("seed".into(), toml::Value::Integer(seed));
    }
    let text =
        toml::to_string(&table).map_err(|e| ScenarioError::Syntax { path: path.into(), message: e.to_string() })?;
    Scenario::parse_str_with(&text, path, controllers).map_err(|e| match e {
        ScenarioError::Syntax { path, message } => match culprit(&path, overrides, controllers) {
            // The file parses alone: name the `--set` that made it fail, not a line of the
            // rewritten scenario nobody sees (issue 60 §4).
            Some((key, value, reason)) => {
                ScenarioError::Invalid { path, key: format!("--set {key}={value}"), problem: reason }
            }
            None => ScenarioError::Syntax {
                path,
                message: format!("{message}(with the overrides applied; line numbers count in the rewritten scenario)"),
            },
        },
        e => e,
    })
}

/// The first override after which the scenario at `path` no longer parses (it parses with none),
/// with its value and the parser's reason without the rewritten text's line and excerpt; `None`
/// when the file fails alone or no single prefix of the overrides can be blamed.
fn culprit<'a>(
    path: &FsPath,
    overrides: &'a [(String, toml::Value)],
    controllers: &ControllerRegistry,
) -> Option<(&'a str, String, String)> {
    let text = scenario_text(path).ok()?;
    let parses =
        |table: &toml::Table| toml::to_string(table).ok().map(|t| Scenario::parse_str_with(&t, path, controllers));
    let mut table: toml::Table = toml::from_str(&text).ok()?;
    if !matches!(parses(&table)?, Ok(_) | Err(ScenarioError::Invalid { .. })) {
        return None;
    }
    for (key, value) in overrides {
        apply_override(&mut table, key, value.clone()).ok()?;
        if let Err(ScenarioError::Syntax { message, .. }) = parses(&table)? {
            return Some((key, value.to_string(), toml_reason(&message)));
        }
    }
    None
}

/// A TOML parse error's reason without its location line and the excerpt of the text.
fn toml_reason(message: &str) -> String {
    let reason: Vec<&str> = message
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("TOML parse error") && !l.starts_with('|') && !l.contains(" | "))
        .filter(|l| !l.chars().all(|c| c == '^' || c == ' ' || c == '|'))
        .collect();
    if reason.is_empty() { message.trim().to_string() } else { reason.join(" ") }
}
