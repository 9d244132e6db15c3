//! Quake III `.map` sources (the editor's file, before q3map2 compiles it): only their
//! entities are read, for `--lights-from` (the light entities q3map2 strips from the BSP).
//!
//! A `.map` is a list of entities `{ "key" "value" ... }`; an entity may hold brushes
//! `{ ( x y z ) ( x y z ) ( x y z ) texture ... }` and patches
//! `{ patchDef2 { texture ( w h 0 0 0 ) ( ( ( ... ) ) ) } }` (or `brushDef`/`brushDef3`
//! blocks), nested braces whose contents are skipped here. Brush and patch tokens are
//! never interpreted, so a map of any brush format reads the same. Keys follow
//! [`crate::entities`]: a repeated key keeps its last value.
//!
//! Untrusted input: the text is scanned once; entity count and nesting depth are
//! bounded; errors name the line.

use crate::entities::Entity;

/// Most entities a `.map` may hold (the largest shipped sources have about 2,000).
pub const MAX_ENTITIES: usize = 1 << 20;
/// Deepest brace nesting accepted inside an entity (a patch needs 4).
pub const MAX_DEPTH: usize = 16;

/// Parses the entities of a `.map` source.
pub fn parse(text: &str) -> Result<Vec<Entity>, String> {
    let mut out: Vec<Entity> = Vec::new();
    let mut depth = 0usize;
    let mut line = 1usize;
    let mut pending_key: Option<String> = None;
    let mut current: Option<(Entity, std::collections::HashMap<String, usize>)> = None;
    let bytes = text.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        let c = bytes[i];
        match c {
            b'\n' => {
                line += 1;
                i += 1;
            }
            b'/' if bytes.get(i + 1) == Some(&b'/') => {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
            }
            b'{' => {
                depth += 1;
                if depth > MAX_DEPTH {
                    return Err(format!("line {line}: braces nested deeper than {MAX_DEPTH}"));
                }
                if depth == 1 {
                    if out.len() >= MAX_ENTITIES {
                        return Err(format!("line {line}: more than {MAX_ENTITIES} entities"));
                    }
                    current = Some((Entity::default(), Default::default()));
                }
                i += 1;
            }
            b'}' => {
                if depth == 0 {
                    return Err(format!("line {line}: '}}' without an open entity"));
                }
                if depth == 1 {
                    if pending_key.is_some() {
                        return Err(format!("line {line}: key without a value"));
                    }
                    if let Some((e, _)) = current.take() {
                        out.push(e);
                    }
                }
                depth -= 1;
                i += 1;
            }
            b'"' => {
                let start = i + 1;
                let mut j = start;
                while j < bytes.len() && bytes[j] != b'"' {
                    if bytes[j] == b'\n' {
                        line += 1;
                    }
                    j += 1;
                }
                if j >= bytes.len() {
                    return Err(format!("line {line}: unterminated string"));
                }
                let s = text[start..j].to_string();
                i = j + 1;
                match depth {
                    0 => return Err(format!("line {line}: string outside an entity")),
                    1 => {
                        let Some((e, keys)) = current.as_mut() else {
                            return Err(format!("line {line}: string outside an entity"));
                        };
                        match pending_key.take() {
                            None => pending_key = Some(s),
                            Some(k) => set(e, keys, k, s),
                        }
                    }
                    // Inside a brush or patch (a texture name in quotes, as some formats write).
                    _ => {}
                }
            }
            c if c.is_ascii_whitespace() || c == 0 => i += 1,
            _ => {
                if depth <= 1 {
                    // Brush contents start with '(' and only appear inside a brush's braces;
                    // a bare word directly inside an entity is malformed.
                    let end = bytes[i..].iter().position(|b| b.is_ascii_whitespace()).map_or(bytes.len(), |p| i + p);
                    return Err(format!("line {line}: unexpected {:?} outside a brush", String::from_utf8_lossy(&bytes[i..end.min(i + 32)])));
                }
                i += 1;
            }
        }
    }
    if depth != 0 {
        return Err("an entity is not closed at the end of the file".into());
    }
    Ok(out)
}

fn set(e: &mut Entity, keys: &mut std::collections::HashMap<String, usize>, k: String, v: String) {
    match keys.get(&k) {
        Some(&i) => e.pairs[i].1 = v,
        None => {
            keys.insert(k.clone(), e.pairs.len());
            e.pairs.push((k, v));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MAP: &str = r#"// entity 0
{
"classname" "worldspawn"
"_minlight" "15"
// brush 0
{
( -64 -64 -16 ) ( -64 -63 -16 ) ( -64 -64 -15 ) base_wall/concrete 0 0 0 0.5 0.5 0 0 0
( 64 64 16 ) ( 64 65 16 ) ( 65 64 16 ) base_wall/concrete 0 0 0 0.5 0.5 0 0 0
}
{
patchDef2
{
base_wall/concrete
( 3 3 0 0 0 )
(
( ( 0 0 0 0 0 ) ( 0 0 0 0 0 ) ( 0 0 0 0 0 ) )
( ( 0 0 0 0 0 ) ( 0 0 0 0 0 ) ( 0 0 0 0 0 ) )
)
}
}
}
{
"classname" "light"
"origin" "1 2 3"
"light" "300"
"light" "250"
"target" "t1"
}
{
"classname" "info_null"
"targetname" "t1"
"origin" "1 2 -100"
}
"#;

    #[test]
    fn entities_are_read_and_brushes_and_patches_skipped() {
        let e = parse(MAP).unwrap();
        assert_eq!(e.len(), 3);
        assert_eq!(e[0].classname(), "worldspawn");
        assert_eq!(e[0].number("_minlight"), Some(15.0));
        assert_eq!(e[0].pairs.len(), 2);
        assert_eq!(e[1].number("light"), Some(250.0), "a repeated key keeps its last value");
        assert_eq!(e[2].vec3("origin"), Some([1.0, 2.0, -100.0]));
    }

    #[test]
    fn malformed_sources_are_errors_with_a_line() {
        for (text, want) in [
            ("{ \"classname\" \"light\"", "not closed"),
            ("}", "line 1"),
            ("{\n\"a\" \"b\" \"c\" }", "line 2: key without a value"),
            ("{ \"a\" \"b }", "unterminated"),
            ("{ bare words }", "outside a brush"),
            ("\"x\" \"y\"", "outside an entity"),
        ] {
            let err = parse(text).unwrap_err();
            assert!(err.contains(want), "{text:?}: {err}");
        }
        let deep = "{".repeat(MAX_DEPTH + 1);
        assert!(parse(&deep).unwrap_err().contains("nested deeper"));
    }
}
