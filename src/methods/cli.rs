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
