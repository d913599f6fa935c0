//! The command-line face of the method table (feature `cli`): value
//! parsers shared by the methods' `Settings`, and a `render` command built
//! for one method, so that each method's `--help` lists only its own flags
//! and a flag of another method is an error that names both.

use clap::{Arg, ArgAction, Command};

use super::{all, by_name, MethodInfo};

/// Parses a count such as `1000000`, `30M` or `2G` (k, M, G: 10³, 10⁶, 10⁹).
pub fn parse_count(s: &str) -> Result<u64, String> {
    let s = s.trim();
    let (num, mult) = match s.chars().last() {
        Some('k' | 'K') => (&s[..s.len() - 1], 1e3),
        Some('m' | 'M') => (&s[..s.len() - 1], 1e6),
        Some('g' | 'G') => (&s[..s.len() - 1], 1e9),
        _ => (s, 1.0),
    };
    let v: f64 = num
        .parse()
        .map_err(|_| format!("expected a count such as 1000000 or 30M, got '{s}'"))?;
    if !(v.is_finite() && v > 0.0) {
        return Err(format!("expected a positive count, got '{s}'"));
    }
    let n = (v * mult).round();
    if n >= u64::MAX as f64 {
        return Err(format!("count too large: '{s}'"));
    }
    Ok(n as u64)
}

/// A finite number > 0 (`--spp`, `--time`): NaN, infinities, zero and
/// negative values are refused when the command line is read, before any
/// loading or rendering.
pub fn parse_positive(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("expected a number, got '{s}'"))?;
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(format!("expected a finite number > 0, got '{s}'"))
    }
}

/// [`parse_count`] for sizes held in a `usize`.
pub fn parse_usize(s: &str) -> Result<usize, String> {
    let n = parse_count(s)?;
    usize::try_from(n).map_err(|_| format!("count too large: '{s}'"))
}

/// Parses `on` / `off`.
pub fn on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("expected on or off, got '{s}'")),
    }
}

/// The `--method` argument itself.
pub fn method_arg() -> Arg {
    let names: Vec<&'static str> = all().iter().map(|m| m.name).collect();
    let mut help = String::from("Rendering method; `--method NAME --help` lists its settings:");
    for m in all() {
        help += &format!("\n  {:<8} {}", m.name, m.about);
    }
    Arg::new("method")
        .short('m')
        .long("method")
        .value_name("NAME")
        .default_value("path")
        .value_parser(clap::builder::PossibleValuesParser::new(names))
        .help(help)
        .action(ArgAction::Set)
}

/// Finds the value of `--method` (or `-m`) in raw arguments, before they
/// are parsed, so that the command for that method can be built. Returns
/// None when it is not given (the default, `path`).
pub fn scan_method(args: &[std::ffi::OsString]) -> Option<String> {
    let mut it = args.iter().map(|a| a.to_string_lossy());
    while let Some(a) = it.next() {
        if a == "--" {
            break;
        }
        if a == "--method" || a == "-m" {
            return it.next().map(|v| v.into_owned());
        }
        if let Some(v) = a.strip_prefix("--method=") {
            return Some(v.to_string());
        }
        if let Some(v) = a.strip_prefix("-m") {
            if !v.is_empty() && !a.starts_with("--") {
                return Some(v.trim_start_matches('=').to_string());
            }
        }
    }
    None
}

/// The long flags a method's settings add, without the leading `--`.
pub fn method_flags(info: &MethodInfo) -> Vec<String> {
    let cmd = (info.args)(Command::new(info.name));
    cmd.get_arguments()
        .filter_map(|a| a.get_long().map(str::to_string))
        .collect()
}

/// When `flag` (as typed, e.g. `--lambda` or `--lambda=3`) is not a flag of
/// `method` but is one of other methods, the message that says so.
pub fn foreign_flag_message(method: &str, flag: &str) -> Option<String> {
    let name = flag.trim_start_matches('-');
    let name = name.split('=').next().unwrap_or(name);
    let owners: Vec<&str> = all()
        .iter()
        .filter(|m| m.name != method && method_flags(m).iter().any(|f| f == name))
        .map(|m| m.name)
        .collect();
    if owners.is_empty() || by_name(method).is_err() {
        return None;
    }
    let owners: Vec<String> = owners.iter().map(|o| format!("'{o}'")).collect();
    let owners = match owners.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} and {last}", rest.join(", ")),
        _ => owners.join(""),
    };
    Some(format!(
        "--{name} does not apply to method '{method}': it is a setting of {owners}. \
         `kalos render --method {method} --help` lists the settings of '{method}'."
    ))
}

/// Builds `method`'s settings from `(name, value)` pairs, for callers that
/// have no command line (the Python package's keyword arguments). Names
/// are the long flags without `--` (`rr-depth`); the values go through the
/// same parsers and checks as `kalos render`, so a bad value gets the
/// command line's message. A switch (`no-decimate`) takes `true` or `on`
/// to be given, `false` or `off` to be left out. A setting of another
/// method gets [`foreign_flag_message`]; a name no method knows gets a
/// message listing the method's settings.
pub fn config_from_pairs(
    method: &str,
    pairs: &[(String, String)],
) -> Result<super::MethodConfig, super::MethodError> {
    use super::MethodError;
    let info = by_name(method)?;
    let cmd = (info.args)(Command::new(info.name))
        .no_binary_name(true)
        .disable_help_flag(true);
    let mut args = Vec::new();
    for (name, value) in pairs {
        let Some(arg) = cmd.get_arguments().find(|a| a.get_long() == Some(name)) else {
            if let Some(msg) = foreign_flag_message(method, name) {
                return Err(MethodError(msg));
            }
            let known: Vec<String> = method_flags(info)
                .iter()
                .map(|f| format!("--{f}"))
                .collect();
            return Err(MethodError(format!(
                "unknown setting --{name} for method '{method}'; its settings: {}",
                known.join(", ")
            )));
        };
        if arg.get_action().takes_values() {
            // `--name=value`: a value may start with '-'
            args.push(format!("--{name}={value}"));
        } else {
            match value.as_str() {
                "true" | "on" => args.push(format!("--{name}")),
                "false" | "off" => {}
                _ => {
                    return Err(MethodError(format!(
                        "--{name} is a switch: expected true or false, got '{value}'"
                    )))
                }
            }
        }
    }
    let matches = cmd.try_get_matches_from(args).map_err(|e| {
        // clap's first line, without its "error: " and the hint about --help
        let text = e.render().to_string();
        let line = text.lines().next().unwrap_or_default();
        MethodError(line.trim_start_matches("error: ").to_string())
    })?;
    let cfg = (info.from_args)(&matches).map_err(|e| MethodError(e.to_string()))?;
    cfg.validate()?;
    Ok(cfg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::methods::MethodConfig;

    fn pairs(p: &[(&str, &str)]) -> Vec<(String, String)> {
        p.iter()
            .map(|(n, v)| (n.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn pairs_set_the_settings() {
        let cfg =
            config_from_pairs("plb", &pairs(&[("lambda", "3"), ("camera-pass", "off")])).unwrap();
        let MethodConfig::Plb(s) = cfg else {
            panic!("not plb: {cfg:?}")
        };
        assert_eq!(s.lambda, 3.0);
        assert!(!s.camera_pass);
        let cfg = config_from_pairs("density", &pairs(&[("no-decimate", "true")])).unwrap();
        let MethodConfig::Density(s) = cfg else {
            panic!("not density: {cfg:?}")
        };
        assert!(!s.decimate);
        assert_eq!(
            config_from_pairs("path", &[]).unwrap(),
            MethodConfig::Path(Default::default())
        );
    }

    #[test]
    fn bad_pairs_get_the_command_lines_messages() {
        let e = config_from_pairs("path", &pairs(&[("lambda", "3")])).unwrap_err();
        assert_eq!(Some(e.0), foreign_flag_message("path", "--lambda"));
        let e = config_from_pairs("plb", &pairs(&[("lambda", "x")])).unwrap_err();
        assert!(e.0.contains("invalid value 'x' for '--lambda"), "{e}");
        let e = config_from_pairs("path", &pairs(&[("rr-depth", "0")])).unwrap_err();
        assert!(e.0.starts_with("--rr-depth must be at least 1"), "{e}");
        let e = config_from_pairs("path", &pairs(&[("frobnicate", "1")])).unwrap_err();
        assert!(
            e.0.contains("--frobnicate") && e.0.contains("--rr-depth"),
            "{e}"
        );
        let e = config_from_pairs("density", &pairs(&[("no-decimate", "2")])).unwrap_err();
        assert!(e.0.contains("is a switch"), "{e}");
        assert!(config_from_pairs("nope", &[]).is_err());
    }
}
