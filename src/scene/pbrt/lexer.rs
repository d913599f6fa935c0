//! Reading a pbrt-v4 file into directives: tokens with their lines, then
//! each directive with its positional arguments and its parameter list.
//!
//! The `pbrt4` crate's tokenizer is not used: in version 0.2.0 it prints
//! every token to stderr (a `dbg!` left in `Tokenizer::token`), slices the
//! text by bytes as if they were characters (a comment with an accented
//! letter panics), misreads a single unbracketed value after two spaces,
//! and reports no position. Its parameter layer (`pbrt4::param`) is used
//! for the declared types and the numeric values.

use pbrt4::param::{Param as PbrtParam, ParamType};

/// One token: a bare word or number, a quoted string (without its quotes),
/// or a bracket.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Tok<'a> {
    Word(&'a str),
    Str(&'a str),
    Open,
    Close,
}

/// A token and the 1-based line it starts on.
#[derive(Clone, Debug)]
pub(super) struct Spanned<'a> {
    pub(super) tok: Tok<'a>,
    pub(super) line: u32,
}

/// Splits pbrt text into tokens: `#` starts a comment to the end of the
/// line, strings are double-quoted (no escapes, as in pbrt), brackets stand
/// alone. An unterminated string is an error at its line.
pub(super) fn tokenize(text: &str) -> Result<Vec<Spanned<'_>>, (u32, String)> {
    let mut out = Vec::new();
    let bytes = text.as_bytes();
    let (mut i, mut line) = (0usize, 1u32);
    while i < bytes.len() {
        let c = bytes[i];
        match c {
            b'\n' => {
                line += 1;
                i += 1;
            }
            b' ' | b'\t' | b'\r' | 0x0c => i += 1,
            b'#' => {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
            }
            b'[' | b']' => {
                let tok = if c == b'[' { Tok::Open } else { Tok::Close };
                out.push(Spanned { tok, line });
                i += 1;
            }
            b'"' => {
                let start = i + 1;
                let first_line = line;
                let mut j = start;
                while j < bytes.len() && bytes[j] != b'"' {
                    if bytes[j] == b'\n' {
                        line += 1;
                    }
                    j += 1;
                }
                if j >= bytes.len() {
                    return Err((first_line, "a string is not closed (missing `\"`)".into()));
                }
                // both ends are ASCII quotes, so the slice is on char boundaries
                out.push(Spanned {
                    tok: Tok::Str(&text[start..j]),
                    line: first_line,
                });
                i = j + 1;
            }
            _ => {
                let start = i;
                while i < bytes.len()
                    && !matches!(
                        bytes[i],
                        b' ' | b'\t' | b'\r' | b'\n' | 0x0c | b'"' | b'[' | b']' | b'#'
                    )
                {
                    i += 1;
                }
                // the stop bytes are ASCII, so the slice is on char boundaries
                out.push(Spanned {
                    tok: Tok::Word(&text[start..i]),
                    line,
                });
            }
        }
    }
    Ok(out)
}

/// A parameter value as written: numbers, strings or booleans.
#[derive(Clone, Debug)]
pub(super) enum Values {
    Nums(Vec<f64>),
    Strs(Vec<String>),
    Bools(Vec<bool>),
}

/// One `"type name" value(s)` parameter.
#[derive(Clone, Debug)]
pub(super) struct Param {
    pub(super) ty: ParamType,
    /// The type as written (`rgb`, `float`...), for messages.
    pub(super) ty_name: String,
    pub(super) name: String,
    pub(super) values: Values,
    pub(super) line: u32,
}

/// A directive: its name, line, positional arguments (the strings and
/// numbers before the parameter list) and parameters.
#[derive(Clone, Debug)]
pub(super) struct Directive {
    pub(super) name: String,
    pub(super) line: u32,
    pub(super) args: Vec<Arg>,
    pub(super) params: Vec<Param>,
}

/// A positional argument.
#[derive(Clone, Debug)]
pub(super) enum Arg {
    Str(String),
    Num(f64),
}

/// Every directive name of pbrt-v4 (a bare word that is not one is an error).
pub(super) const DIRECTIVES: &[&str] = &[
    "Accelerator",
    "ActiveTransform",
    "AreaLightSource",
    "Attribute",
    "AttributeBegin",
    "AttributeEnd",
    "Camera",
    "ColorSpace",
    "ConcatTransform",
    "CoordinateSystem",
    "CoordSysTransform",
    "Film",
    "Identity",
    "Import",
    "Include",
    "Integrator",
    "LightSource",
    "LookAt",
    "MakeNamedMaterial",
    "MakeNamedMedium",
    "Material",
    "MediumInterface",
    "NamedMaterial",
    "ObjectBegin",
    "ObjectEnd",
    "ObjectInstance",
    "Option",
    "PixelFilter",
    "ReverseOrientation",
    "Rotate",
    "Sampler",
    "Scale",
    "Shape",
    "Texture",
    "Transform",
    "TransformBegin",
    "TransformEnd",
    "TransformTimes",
    "Translate",
    "WorldBegin",
    "WorldEnd",
];

/// Groups tokens into directives. The positional arguments of each
/// directive are read as they come (strings, numbers, and one bracketed
/// list of numbers for `Transform`/`ConcatTransform`); then quoted
/// `"type name"` strings each start a parameter. Errors carry the line.
pub(super) fn directives(toks: &[Spanned<'_>]) -> Result<Vec<Directive>, (u32, String)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < toks.len() {
        let t = &toks[i];
        let name = match t.tok {
            Tok::Word(w) if DIRECTIVES.contains(&w) => w,
            Tok::Word(w) => {
                return Err((t.line, format!("unknown directive `{w}`: expected a pbrt-v4 directive such as Shape, Material or AttributeBegin")))
            }
            Tok::Str(s) => return Err((t.line, format!("unexpected string \"{s}\": expected a directive"))),
            Tok::Open | Tok::Close => return Err((t.line, "unexpected bracket: expected a directive".into())),
        };
        let line = t.line;
        i += 1;
        let mut d = Directive {
            name: name.to_string(),
            line,
            args: Vec::new(),
            params: Vec::new(),
        };
        // Positional arguments: how many strings a directive takes before
        // its parameter list (a quoted string after those starts a parameter)
        let n_str = match name {
            "Texture" => 3,
            "MediumInterface" => 2,
            "Accelerator" | "ActiveTransform" | "AreaLightSource" | "Attribute" | "Camera"
            | "ColorSpace" | "CoordinateSystem" | "CoordSysTransform" | "Film" | "Import"
            | "Include" | "Integrator" | "LightSource" | "MakeNamedMaterial"
            | "MakeNamedMedium" | "Material" | "NamedMaterial" | "ObjectBegin"
            | "ObjectInstance" | "PixelFilter" | "Sampler" | "Shape" => 1,
            _ => 0,
        };
        let mut strs = 0;
        while i < toks.len() {
            match &toks[i].tok {
                Tok::Word(w) if DIRECTIVES.contains(w) => break,
                Tok::Word(w) => {
                    let v = parse_num(w).ok_or_else(|| {
                        (
                            toks[i].line,
                            format!("`{name}`: expected a number, found `{w}`"),
                        )
                    })?;
                    d.args.push(Arg::Num(v));
                    i += 1;
                }
                Tok::Open if matches!(name, "Transform" | "ConcatTransform") => {
                    i += 1;
                    while i < toks.len() && toks[i].tok != Tok::Close {
                        match toks[i].tok {
                            Tok::Word(w) => {
                                d.args.push(Arg::Num(parse_num(w).ok_or_else(|| {
                                    (
                                        toks[i].line,
                                        format!("`{name}`: expected a number, found `{w}`"),
                                    )
                                })?))
                            }
                            _ => {
                                return Err((
                                    toks[i].line,
                                    format!("`{name}`: expected 16 numbers in brackets"),
                                ))
                            }
                        }
                        i += 1;
                    }
                    if i >= toks.len() {
                        return Err((line, format!("`{name}`: the bracket is not closed")));
                    }
                    i += 1;
                }
                Tok::Str(s) if strs < n_str => {
                    d.args.push(Arg::Str(s.to_string()));
                    strs += 1;
                    i += 1;
                }
                Tok::Str(_) => break,
                Tok::Open | Tok::Close => {
                    return Err((toks[i].line, format!("`{name}`: unexpected bracket")))
                }
            }
        }
        // The parameter list
        while i < toks.len() {
            match &toks[i].tok {
                Tok::Str(_) => {
                    let (p, next) = read_param(toks, i, name)?;
                    if d.params.iter().any(|q| q.name == p.name) {
                        return Err((p.line, format!("parameter `{}` given twice", p.name)));
                    }
                    d.params.push(p);
                    i = next;
                }
                _ => break,
            }
        }
        out.push(d);
    }
    Ok(out)
}

/// A number as pbrt writes them (the `f64` grammar; non-finite is refused).
fn parse_num(w: &str) -> Option<f64> {
    w.parse::<f64>().ok().filter(|v| v.is_finite())
}

/// Reads the parameter whose `"type name"` is at `i`; returns it and the
/// index after its value(s).
fn read_param(toks: &[Spanned<'_>], i: usize, dir: &str) -> Result<(Param, usize), (u32, String)> {
    let (decl, line) = match toks[i].tok {
        Tok::Str(s) => (s, toks[i].line),
        _ => {
            return Err((
                toks[i].line,
                format!("`{dir}`: expected a \"type name\" parameter"),
            ))
        }
    };
    let words: Vec<&str> = decl.split_whitespace().collect();
    if words.len() != 2 {
        return Err((
            line,
            format!("`{dir}`: parameter \"{decl}\" should be \"type name\" (for example \"float radius\")"),
        ));
    }
    // pbrt4's parameter layer checks the declared type; "point"/"vector"/
    // "color" are pbrt-v3 spellings that pbrt-v4 still reads
    let ty_word = match words[0] {
        "point" => "point3",
        "vector" => "vector3",
        "color" => "rgb",
        w => w,
    };
    let ty = PbrtParam::new(&format!("{ty_word} {}", words[1]), "")
        .map(|p| p.ty)
        .map_err(|_| {
            (
                line,
                format!(
                    "`{dir}`: unknown parameter type `{}` in \"{decl}\": expected integer, float, \
                     point2, vector2, point3, vector3, normal3, rgb, spectrum, blackbody, bool, \
                     string or texture",
                    words[0]
                ),
            )
        })?;
    // The value(s): one bare token, or a bracketed list
    let mut j = i + 1;
    let mut raw: Vec<&Spanned<'_>> = Vec::new();
    match toks.get(j).map(|t| &t.tok) {
        Some(Tok::Open) => {
            j += 1;
            while j < toks.len() && toks[j].tok != Tok::Close {
                if let Tok::Word(w) = toks[j].tok {
                    if DIRECTIVES.contains(&w) {
                        break;
                    }
                }
                raw.push(&toks[j]);
                j += 1;
            }
            if j >= toks.len() || toks[j].tok != Tok::Close {
                return Err((
                    line,
                    format!("`{dir}`: the value of \"{decl}\" has no closing `]`"),
                ));
            }
            j += 1;
        }
        Some(Tok::Word(w)) if !DIRECTIVES.contains(w) => {
            raw.push(&toks[j]);
            j += 1;
        }
        Some(Tok::Str(_)) => {
            raw.push(&toks[j]);
            j += 1;
        }
        _ => return Err((line, format!("`{dir}`: parameter \"{decl}\" has no value"))),
    }
    let values = match ty {
        ParamType::String | ParamType::Texture => Values::Strs(
            raw.iter()
                .map(|t| match t.tok {
                    Tok::Str(s) => Ok(s.to_string()),
                    _ => Err((t.line, format!("`{dir}`: \"{decl}\" takes quoted strings"))),
                })
                .collect::<Result<_, _>>()?,
        ),
        ParamType::Boolean => Values::Bools(
            raw.iter()
                .map(|t| match t.tok {
                    Tok::Str("true") | Tok::Word("true") => Ok(true),
                    Tok::Str("false") | Tok::Word("false") => Ok(false),
                    _ => Err((t.line, format!("`{dir}`: \"{decl}\" takes true or false"))),
                })
                .collect::<Result<_, _>>()?,
        ),
        // a spectrum is numbers (λ, value pairs) or one string (a named
        // spectrum or a file)
        ParamType::Spectrum if raw.iter().all(|t| matches!(t.tok, Tok::Str(_))) => Values::Strs(
            raw.iter()
                .filter_map(|t| match t.tok {
                    Tok::Str(s) => Some(s.to_string()),
                    _ => None,
                })
                .collect(),
        ),
        _ => {
            let mut nums = Vec::with_capacity(raw.len());
            for t in &raw {
                let v = match t.tok {
                    Tok::Word(w) => parse_num(w),
                    _ => None,
                };
                match v {
                    Some(v) => nums.push(v),
                    None => {
                        return Err((
                            t.line,
                            format!("`{dir}`: \"{decl}\" takes numbers, found {}", show(&t.tok)),
                        ))
                    }
                }
            }
            Values::Nums(nums)
        }
    };
    Ok((
        Param {
            ty,
            ty_name: ty_word.to_string(),
            name: words[1].to_string(),
            values,
            line,
        },
        j,
    ))
}

fn show(t: &Tok<'_>) -> String {
    match t {
        Tok::Word(w) => format!("`{w}`"),
        Tok::Str(s) => format!("\"{s}\""),
        Tok::Open => "`[`".into(),
        Tok::Close => "`]`".into(),
    }
}
