//! The entity lump: `{ "key" "value" ... }` blocks of text.
//!
//! Keys keep their order of appearance; a repeated key keeps its last value (as the
//! engine's spawn code does). Parsing is total: malformed text gives an error naming the
//! line, never a panic.

/// One entity: its key/value pairs in file order, without duplicates.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Entity {
    pub pairs: Vec<(String, String)>,
}

impl Entity {
    pub fn get(&self, key: &str) -> Option<&str> {
        self.pairs.iter().find(|(k, _)| k.eq_ignore_ascii_case(key)).map(|(_, v)| v.as_str())
    }
    pub fn classname(&self) -> &str {
        self.get("classname").unwrap_or("")
    }
    /// A vector key such as `origin` or `_color`: three numbers separated by spaces.
    pub fn vec3(&self, key: &str) -> Option<[f64; 3]> {
        let mut it = self.get(key)?.split_whitespace().map(|t| t.parse::<f64>().ok());
        let v = [it.next()??, it.next()??, it.next()??];
        v.iter().all(|x| x.is_finite()).then_some(v)
    }
    pub fn number(&self, key: &str) -> Option<f64> {
        self.get(key)?.trim().parse::<f64>().ok().filter(|x| x.is_finite())
    }
    /// Sets `key`, with `index` (key -> position in `pairs`) kept alongside so that an
    /// entity with many keys parses in linear time.
    fn set(&mut self, index: &mut std::collections::HashMap<String, usize>, key: String, value: String) {
        match index.get(&key) {
            Some(&i) => self.pairs[i].1 = value,
            None => {
                index.insert(key.clone(), self.pairs.len());
                self.pairs.push((key, value));
            }
        }
    }
}

/// Parses the entity lump text.
pub fn parse(text: &str) -> Result<Vec<Entity>, String> {
    let mut out = Vec::new();
    let mut chars = text.char_indices().peekable();
    let mut line = 1usize;
    let mut current: Option<Entity> = None;
    let mut pending_key: Option<String> = None;
    let mut keys = std::collections::HashMap::new();
    while let Some((_, c)) = chars.next() {
        match c {
            '\n' => line += 1,
            c if c.is_whitespace() || c == '\0' => {}
            '/' if matches!(chars.peek(), Some((_, '/'))) => {
                for (_, c) in chars.by_ref() {
                    if c == '\n' {
                        line += 1;
                        break;
                    }
                }
            }
            '{' => {
                if current.is_some() {
                    return Err(format!("line {line}: '{{' inside an entity"));
                }
                current = Some(Entity::default());
                keys.clear();
            }
            '}' => {
                let Some(e) = current.take() else {
                    return Err(format!("line {line}: '}}' without an open entity"));
                };
                if pending_key.is_some() {
                    return Err(format!("line {line}: key without a value"));
                }
                out.push(e);
            }
            '"' => {
                let mut s = String::new();
                let mut closed = false;
                for (_, c) in chars.by_ref() {
                    if c == '"' {
                        closed = true;
                        break;
                    }
                    if c == '\n' {
                        line += 1;
                    }
                    s.push(c);
                }
                if !closed {
                    return Err(format!("line {line}: unterminated string"));
                }
                let Some(e) = current.as_mut() else {
                    return Err(format!("line {line}: string outside an entity"));
                };
                match pending_key.take() {
                    None => pending_key = Some(s),
                    Some(k) => e.set(&mut keys, k, s),
                }
            }
            other => return Err(format!("line {line}: unexpected character {other:?}")),
        }
    }
    if current.is_some() {
        return Err("entity not closed at end of lump".into());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_blocks_and_keeps_last_duplicate() {
        let e = parse("{\n\"classname\" \"worldspawn\"\n}\n{ \"origin\" \"1 2 3\" \"light\" \"300\" \"light\" \"400\" }\0").unwrap();
        assert_eq!(e.len(), 2);
        assert_eq!(e[0].classname(), "worldspawn");
        assert_eq!(e[1].vec3("origin"), Some([1.0, 2.0, 3.0]));
        assert_eq!(e[1].number("light"), Some(400.0));
        assert_eq!(e[1].pairs.len(), 2);
    }

    /// One entity with 100k distinct keys (about 2 MB of text, within a map's size):
    /// parsing stays linear, not quadratic in the number of keys.
    #[test]
    fn many_keys_parse_in_linear_time() {
        let mut text = String::from("{\n");
        for i in 0..100_000 {
            text.push_str(&format!("\"key{i}\" \"{i}\"\n"));
        }
        text.push_str("\"key7\" \"last\"\n}\n");
        let t = std::time::Instant::now();
        let e = parse(&text).unwrap();
        assert!(t.elapsed() < std::time::Duration::from_secs(2), "{:?}", t.elapsed());
        assert_eq!(e[0].pairs.len(), 100_000);
        assert_eq!(e[0].get("key7"), Some("last"));
        assert_eq!(e[0].pairs[7], ("key7".to_string(), "last".to_string()));
    }

    #[test]
    fn reports_malformed_text() {
        assert!(parse("{ \"a\" }").unwrap_err().contains("key without a value"));
        assert!(parse("{ \"a\" \"b").unwrap_err().contains("unterminated"));
        assert!(parse("}").is_err());
        assert!(parse("{ {").is_err());
        assert!(parse("{ \"a\" \"b\"").is_err());
        assert!(parse("x").is_err());
    }
}
