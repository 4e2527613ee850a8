//! bindings/sie.hpp mirrors parts of include/sie.h by hand: `sie::Summary` holds every field of
//! `sie_summary` (copied by `Context::summary()`, and the fields the library reads back copied by
//! `Context::set_warm_start()`), and each `enum class` lists the constants of one C enum. These
//! tests read both files and fail where they disagree, as
//! bindings/python/tests/test_header_mirror.py does for the Python mirror.

use std::collections::BTreeMap;
use std::path::Path;

fn read(path: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
    std::fs::read_to_string(&path).unwrap_or_else(|error| panic!("{}: {error}", path.display()))
}

/// `text` with every comment blanked out byte for byte, so that offsets into it are offsets into
/// `text` (which keeps the documentation).
fn without_comments(text: &str) -> String {
    let mut code = text.as_bytes().to_vec();
    let mut index = 0;
    while index < code.len() {
        let end = if code[index..].starts_with(b"/*") {
            text[index..].find("*/").map_or(code.len(), |end| index + end + 2)
        } else if code[index..].starts_with(b"//") {
            text[index..].find('\n').map_or(code.len(), |end| index + end)
        } else {
            index += 1;
            continue;
        };
        for byte in &mut code[index..end] {
            if *byte != b'\n' {
                *byte = b' ';
            }
        }
        index = end;
    }
    String::from_utf8(code).expect("comments are blanked whole")
}

/// The offsets of the body of the first block after `code[from..]`: from after its `{` to its
/// matching `}`.
fn block_after(code: &str, from: usize) -> std::ops::Range<usize> {
    let open = from + code[from..].find('{').expect("a block follows");
    let mut depth = 0;
    for (offset, character) in code[open..].char_indices() {
        match character {
            '{' => depth += 1,
            '}' => {
                depth -= 1;
                if depth == 0 {
                    return open + 1..open + offset;
                }
            }
            _ => {}
        }
    }
    panic!(
        "unbalanced braces after {:?}",
        &code[from..code.len().min(from + 60)]
    );
}

/// The body of the block opened by the line starting with `opening` (whitespace-trimmed).
fn body_of<'a>(code: &'a str, opening: &str) -> &'a str {
    let start = line_starts(code)
        .find(|&start| code[start..].trim_start().starts_with(opening))
        .unwrap_or_else(|| panic!("no line starts with {opening:?}"));
    &code[block_after(code, start)]
}

fn line_starts(code: &str) -> impl Iterator<Item = usize> + '_ {
    std::iter::once(0).chain(code.match_indices('\n').map(|(index, _)| index + 1))
}

/// Runs of whitespace as one space.
fn squeeze(text: &str) -> String {
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}

#[derive(Debug)]
struct Field {
    name: String,
    /// The type without the array length.
    ty: String,
    length: Option<usize>,
    /// The comments before the declaration.
    doc: String,
}

/// The fields of a struct body: `doc_text` is the body with its comments, `code` the same
/// body with them blanked out.
fn fields(doc_text: &str, code: &str, parse: fn(&str) -> (String, String)) -> Vec<Field> {
    let mut fields = Vec::new();
    let mut start = 0;
    for (end, _) in code.match_indices(';') {
        let declaration = squeeze(&code[start..end]);
        let doc = doc_text[start..end].to_string();
        start = end + 1;
        let (ty, declarator) = parse(&declaration);
        let (name, length) = match declarator.split_once('[') {
            Some((name, length)) => {
                let length = length.trim_end_matches(']').parse().expect("array length");
                (name.to_string(), Some(length))
            }
            None => (declarator, None),
        };
        fields.push(Field {
            name,
            ty,
            length,
            doc,
        });
    }
    fields
}

/// `double sigma[3]` -> ("double", "sigma[3]").
fn c_declaration(declaration: &str) -> (String, String) {
    let (ty, name) = declaration.rsplit_once(' ').expect("type and name");
    (ty.to_string(), name.to_string())
}

/// `std::array<double, 3> sigma{}` -> ("std::array<double, 3>", "sigma"); `double rmse = 0.0`
/// -> ("double", "rmse").
fn cpp_declaration(declaration: &str) -> (String, String) {
    let declaration = declaration.split(" = ").next().unwrap_or_default();
    let declaration = declaration.strip_suffix("{}").unwrap_or(declaration);
    c_declaration(declaration)
}

fn sie_summary_fields() -> Vec<Field> {
    let header = read("include/sie.h");
    let code = without_comments(&header);
    let start = line_starts(&code)
        .find(|&start| code[start..].starts_with("typedef struct sie_summary {"))
        .expect("sie.h declares sie_summary");
    let body = block_after(&code, start);
    fields(&header[body.clone()], &code[body], c_declaration)
}

fn cpp_summary_fields(hpp: &str) -> Vec<Field> {
    let code = without_comments(hpp);
    let start = line_starts(&code)
        .find(|&start| code[start..].starts_with("struct Summary {"))
        .expect("sie.hpp declares Summary");
    let body = block_after(&code, start);
    fields(&hpp[body.clone()], &code[body], cpp_declaration)
}

/// C enum name -> its constants, in order.
fn c_enums() -> BTreeMap<String, Vec<String>> {
    let code = without_comments(&read("include/sie.h"));
    let mut enums = BTreeMap::new();
    for start in line_starts(&code) {
        let line = code[start..].lines().next().unwrap_or_default();
        let Some(name) = line.strip_prefix("enum ").filter(|name| name.starts_with("sie_")) else {
            continue;
        };
        let constants = code[block_after(&code, start)]
            .split(',')
            .filter_map(|constant| constant.split('=').next())
            .map(str::trim)
            .filter(|constant| !constant.is_empty())
            .map(String::from)
            .collect();
        enums.insert(name.trim().to_string(), constants);
    }
    enums
}

/// A C++ `enum class`: its underlying type and the C constants its values are.
struct CppEnum {
    underlying: String,
    constants: Vec<String>,
}

fn cpp_enums(hpp: &str) -> BTreeMap<String, CppEnum> {
    let code = without_comments(hpp);
    let mut enums = BTreeMap::new();
    for start in line_starts(&code) {
        let line = code[start..].lines().next().unwrap_or_default();
        let Some(declaration) = line.strip_prefix("enum class ") else {
            continue;
        };
        let declaration = declaration.trim_end_matches('{').trim();
        let (name, underlying) = declaration.split_once(':').unwrap_or((declaration, ""));
        let constants = code[block_after(&code, start)]
            .split(',')
            .filter_map(|value| {
                value
                    .split_once('=')
                    .map(|(_, constant)| constant.trim().to_string())
            })
            .collect();
        enums.insert(
            name.trim().to_string(),
            CppEnum {
                underlying: underlying.trim().to_string(),
                constants,
            },
        );
    }
    enums
}

/// Which C enum each C++ enum class mirrors (the one whose constants its values are).
fn mirrored_c_enum<'a>(cpp: &CppEnum, c_enums: &'a BTreeMap<String, Vec<String>>) -> Option<&'a str> {
    let first = cpp.constants.first()?;
    c_enums
        .iter()
        .find(|(_, constants)| constants.contains(first))
        .map(|(name, _)| name.as_str())
}

/// The C++ spelling of a C scalar type in the mirror.
fn cpp_scalar(c_type: &str) -> String {
    if c_type.ends_with("_t") {
        format!("std::{c_type}")
    } else {
        c_type.to_string()
    }
}

/// Why the C++ field cannot hold the C one, if it cannot. A `uint32_t` that the header
/// documents as "a `sie_x`" may be the enum class mirroring `sie_x`.
fn type_mismatch(c: &Field, cpp: &Field, hpp: &str) -> Option<String> {
    let scalar = cpp_scalar(&c.ty);
    let expected = match c.length {
        Some(length) => format!("std::array<{scalar}, {length}>"),
        None => scalar.clone(),
    };
    if cpp.ty == expected {
        return None;
    }
    let cpp_enums = cpp_enums(hpp);
    let Some(cpp_enum) = cpp_enums.get(&cpp.ty).filter(|_| c.length.is_none()) else {
        return Some(format!(
            "Summary::{} is {}, sie_summary's is {}",
            cpp.name, cpp.ty, c.ty
        ));
    };
    let c_enums = c_enums();
    let mirrored = mirrored_c_enum(cpp_enum, &c_enums).unwrap_or("no C enum");
    if cpp_enum.underlying != scalar {
        return Some(format!(
            "Summary::{} is enum class {} over {:?}, sie_summary's is {}",
            cpp.name, cpp.ty, cpp_enum.underlying, c.ty
        ));
    }
    if !c.doc.contains(&format!("`{mirrored}`")) {
        return Some(format!(
            "Summary::{} is {} (mirroring {mirrored}), but sie.h does not document sie_summary.{} as a \
             `{mirrored}`",
            cpp.name, cpp.ty, c.name
        ));
    }
    None
}

#[test]
fn cpp_summary_has_every_sie_summary_field_with_a_compatible_type() {
    let hpp = read("bindings/sie.hpp");
    let c_fields = sie_summary_fields();
    let cpp_fields = cpp_summary_fields(&hpp);
    assert!(c_fields.len() >= 20, "sie.h: {c_fields:?}");
    let mut problems = Vec::new();
    for c in &c_fields {
        match cpp_fields.iter().find(|cpp| cpp.name == c.name) {
            None => problems.push(format!("sie::Summary has no field {} ({})", c.name, c.ty)),
            Some(cpp) => problems.extend(type_mismatch(c, cpp, &hpp)),
        }
    }
    for cpp in &cpp_fields {
        if !c_fields.iter().any(|c| c.name == cpp.name) {
            problems.push(format!(
                "sie::Summary::{} is not a field of sie_summary",
                cpp.name
            ));
        }
    }
    assert!(
        problems.is_empty(),
        "bindings/sie.hpp:\n  {}",
        problems.join("\n  ")
    );
}

/// The statements of a function body, whitespace squeezed (also those in nested blocks).
fn statements(body: &str) -> impl Iterator<Item = String> + '_ {
    body.split([';', '{', '}']).map(squeeze)
}

/// Whether `body` assigns `to.FIELD` from an expression of `from.FIELD`; arrays element by
/// element in a loop over all of them (`for (std::size_t i = 0; i < N; ++i)`).
fn copies(body: &str, to: &str, from: &str, field: &Field) -> bool {
    let name = &field.name;
    let Some(length) = field.length else {
        return statements(body).any(|statement| {
            statement.starts_with(&format!("{to}.{name} = "))
                && (statement.ends_with(&format!(" {from}.{name}"))
                    || statement.ends_with(&format!("({from}.{name})")))
        });
    };
    let element = format!("{to}.{name}[i] = {from}.{name}[i]");
    let bound = format!("for (std::size_t i = 0; i < {length}; ++i)");
    body.match_indices("for (").any(|(start, _)| {
        let header_end = start + body[start..].find(')').unwrap_or(0) + 1;
        squeeze(&body[start..header_end]) == bound
            && statements(&body[block_after(body, start)]).any(|statement| statement == element)
    })
}

#[test]
fn context_summary_copies_every_field() {
    let hpp = read("bindings/sie.hpp");
    let code = without_comments(&hpp);
    let body = body_of(&code, "Summary summary() const {");
    let missing: Vec<_> = sie_summary_fields()
        .into_iter()
        .filter(|field| !copies(body, "s", "raw", field))
        .map(|field| field.name)
        .collect();
    assert!(
        missing.is_empty(),
        "sie::Context::summary() does not copy sie_summary's {missing:?} (as `s.f = raw.f;`, a \
         static_cast of it, or an array element by element)"
    );
}

/// `Context::set_warm_start` fills a `sie_summary` from a `Summary`: with at least the fields
/// that `read_warm_start` (src/ffi/input.rs) reads.
#[test]
fn set_warm_start_copies_every_field_the_library_reads() {
    let input = without_comments(&read("src/ffi/input.rs"));
    let reader = body_of(&input, "pub(crate) unsafe fn read_warm_start(");
    let read_fields: Vec<&str> = reader
        .split("(*ptr).")
        .skip(1)
        .map(|rest| {
            rest.split(|c: char| !c.is_alphanumeric() && c != '_')
                .next()
                .unwrap_or(rest)
        })
        .collect();
    assert!(
        read_fields.contains(&"sigma"),
        "read_warm_start reads {read_fields:?}"
    );

    let hpp = without_comments(&read("bindings/sie.hpp"));
    let body = body_of(&hpp, "Context &set_warm_start(const Summary &previous) {");
    let missing: Vec<_> = sie_summary_fields()
        .into_iter()
        .filter(|field| read_fields.contains(&field.name.as_str()))
        .filter(|field| !copies(body, "raw", "previous", field))
        .map(|field| field.name)
        .collect();
    assert!(
        missing.is_empty(),
        "sie::Context::set_warm_start() does not pass {missing:?}, which sie_context_set_warm_start reads"
    );
}

#[test]
fn every_c_enum_has_an_enum_class_with_all_its_values() {
    let c_enums = c_enums();
    let cpp_enums = cpp_enums(&read("bindings/sie.hpp"));
    assert_eq!(c_enums.len(), 11, "{:?}", c_enums.keys());
    let mut problems = Vec::new();
    let mut mirrors: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for (name, cpp) in &cpp_enums {
        let Some(c_name) = mirrored_c_enum(cpp, &c_enums) else {
            problems.push(format!(
                "enum class {name} mirrors no C enum ({:?})",
                cpp.constants
            ));
            continue;
        };
        mirrors.entry(c_name).or_default().push(name);
        if cpp.underlying != "std::uint32_t" {
            problems.push(format!(
                "enum class {name} is over {:?}, not std::uint32_t",
                cpp.underlying
            ));
        }
        let c_constants = &c_enums[c_name];
        for constant in &cpp.constants {
            if !c_constants.contains(constant) {
                problems.push(format!("enum class {name} ({c_name}) has {constant}"));
            }
        }
        for constant in c_constants {
            if !cpp.constants.contains(constant) {
                problems.push(format!("enum class {name} has no value for {constant}"));
            }
        }
    }
    for c_name in c_enums.keys() {
        match mirrors.get(c_name.as_str()).map(Vec::len) {
            Some(1) => {}
            None => problems.push(format!("no enum class mirrors {c_name}")),
            Some(_) => problems.push(format!("{c_name} is mirrored by {:?}", mirrors[c_name.as_str()])),
        }
    }
    assert!(
        problems.is_empty(),
        "bindings/sie.hpp:\n  {}",
        problems.join("\n  ")
    );
}

/// The names of the functions sie.h declares.
fn c_functions() -> Vec<String> {
    let code = without_comments(&read("include/sie.h"));
    let mut names: Vec<String> = code
        .match_indices("sie_")
        .filter(|&(start, _)| {
            // A declaration: the name is followed by `(` and preceded by a return type on the
            // same line (`sie_status sie_context_new(` ...), not by another identifier's tail.
            let line_start = code[..start].rfind('\n').map_or(0, |i| i + 1);
            let before = code[line_start..start].trim_end();
            !before.is_empty() && !before.starts_with('#') && !before.ends_with(['(', ','])
        })
        .filter_map(|(start, _)| {
            let name: String = code[start..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            code[start + name.len()..].starts_with('(').then_some(name)
        })
        .collect();
    names.sort();
    names.dedup();
    names
}

/// sie::Context wraps the whole C API: every function of sie.h is called somewhere in sie.hpp
/// (a new getter without a C++ method fails here).
#[test]
fn every_c_function_is_used_by_the_wrapper() {
    let functions = c_functions();
    assert!(
        functions.len() >= 40 && functions.iter().any(|f| f == "sie_context_get_pose_uncertainty"),
        "sie.h functions: {functions:?}"
    );
    let code = without_comments(&read("bindings/sie.hpp"));
    let unused: Vec<_> = functions
        .iter()
        .filter(|name| !code.contains(&format!("{name}(")) && !code.contains(&format!("&{name})")))
        .collect();
    assert!(unused.is_empty(), "bindings/sie.hpp never calls {unused:?}");
}
