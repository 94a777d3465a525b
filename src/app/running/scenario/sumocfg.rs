//! `smlworld run x.sumocfg`: a SUMO configuration read as the scenario it describes (SUMO's
//! `docs/web/docs/Basics/Using_the_Command_Line_Applications.md`, configuration files).
//!
//! Read: `net-file` (the `map`), `route-files` (comma-separated: the `demand`), `begin`
//! (`demand_begin`: the run starts at that SUMO time), `end` (`duration = end - begin`), and
//! `step-length` (our dynamics step: `rates.dynamics = 1 / step-length`, sensors and control at
//! most as fast); paths are relative to the configuration, as in SUMO. Our defaults apply to
//! everything else, and every other option the file sets is named in one warning.

use std::path::Path as FsPath;

use super::ScenarioError;
use crate::map::opendrive::xml::{Element, parse_root};

/// The options read; the others are listed in a warning.
const KNOWN: [&str; 5] = ["net-file", "route-files", "begin", "end", "step-length"];

/// The scenario TOML for the SUMO configuration `text` (read from `path`).
pub fn scenario_text(text: &str, path: &FsPath) -> Result<String, ScenarioError> {
    let bad = |key: &str, problem: String| ScenarioError::Invalid { path: path.into(), key: key.into(), problem };
    let root = parse_root(text, path)
        .map_err(|e| bad("configuration", e.to_string()))?
        .filter(|r| r.name == "configuration")
        .ok_or_else(|| bad("configuration", "no <configuration> root element: not a SUMO configuration".into()))?;
    // Options are the grandchildren (<input><net-file value=".."/></input>), or children.
    let mut options: Vec<&Element> = Vec::new();
    for c in &root.children {
        if c.children.is_empty() {
            options.push(c);
        } else {
            options.extend(c.children.iter());
        }
    }
    let value = |name: &str| options.iter().find(|o| o.name == name).and_then(|o| o.attr("value"));
    let number = |name: &str| -> Result<Option<f64>, ScenarioError> {
        value(name)
            .map(|v| {
                v.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| bad(name, format!("`{v}` is not a number of seconds")))
            })
            .transpose()
    };
    let mut table = toml::Table::new();
    let net = value("net-file").ok_or_else(|| bad("net-file", "is missing: a configuration needs a network".into()))?;
    table.insert("map".into(), toml::Value::String(net.trim().to_string()));
    if let Some(routes) = value("route-files") {
        let files: Vec<toml::Value> = routes
            .split(',')
            .map(str::trim)
            .filter(|f| !f.is_empty())
            .map(|f| toml::Value::String(f.to_string()))
            .collect();
        table.insert("demand".into(), toml::Value::Array(files));
    }
    let begin = number("begin")?.unwrap_or(0.0);
    if begin < 0.0 {
        return Err(bad("begin", "must be 0 or more".into()));
    }
    table.insert("demand_begin".into(), toml::Value::Float(begin));
    if let Some(end) = number("end")? {
        if end <= begin {
            return Err(bad("end", format!("{end} s is not after begin ({begin} s)")));
        }
        table.insert("duration".into(), toml::Value::Float(end - begin));
    }
    if let Some(step) = number("step-length")? {
        if step <= 0.0 {
            return Err(bad("step-length", "must be above 0 s".into()));
        }
        let hz = 1.0 / step;
        let defaults = crate::sim::Rates::default();
        let mut rates = toml::Table::new();
        rates.insert("dynamics".into(), toml::Value::Float(hz));
        rates.insert("control".into(), toml::Value::Float(defaults.control.min(hz)));
        rates.insert("sensors".into(), toml::Value::Float(defaults.sensors.min(hz)));
        table.insert("rates".into(), toml::Value::Table(rates));
    }
    let unknown: Vec<&str> = options.iter().map(|o| o.name.as_str()).filter(|n| !KNOWN.contains(n)).collect();
    if !unknown.is_empty() {
        tracing::warn!("{}: SUMO options not read (our defaults apply): {}", path.display(), unknown.join(", "));
    }
    toml::to_string(&table).map_err(|e| bad("configuration", e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_configuration_becomes_map_demand_duration_and_rates() {
        let text = r#"<configuration>
    <input><net-file value="n.net.xml"/><route-files value="a.rou.xml, b.rou.xml"/></input>
    <time><begin value="100"/><end value="700"/><step-length value="0.1"/></time>
    <report><verbose value="true"/></report>
</configuration>"#;
        let toml = scenario_text(text, FsPath::new("x.sumocfg")).unwrap();
        let t: toml::Table = toml::from_str(&toml).unwrap();
        assert_eq!(t["map"].as_str(), Some("n.net.xml"));
        assert_eq!(t["demand"].as_array().unwrap().len(), 2);
        assert_eq!(t["duration"].as_float(), Some(600.0));
        assert_eq!(t["demand_begin"].as_float(), Some(100.0));
        assert!((t["rates"]["dynamics"].as_float().unwrap() - 10.0).abs() < 1e-9);
        assert_eq!(t["rates"]["control"].as_float(), Some(10.0));
    }
}
