//! The coordinate system a `.prj` beside a grid names.
//!
//! A `.prj` holds Well-Known Text (WKT 1, often in Esri's dialect, or WKT 2)
//! or, from some tools, a PROJ.4 string. What terrachunk takes from it:
//! whether the CRS is geographic or projected, its EPSG code where the WKT
//! carries one for the whole CRS (WKT 1's last `AUTHORITY["EPSG","code"]`,
//! WKT 2's `ID["EPSG",code]`), and a PROJ.4 string as it stands. A WKT
//! without a code keeps only the kind (geographic or projected); the grid
//! then gets no placement, and the build says so.

use crate::heightfield::Crs;

/// What a `.prj`'s text says: the CRS, and a PROJ.4 definition when the
/// text is one.
pub(super) fn crs_of_prj(text: &str) -> (Crs, Option<String>) {
    let text = text.trim_start_matches('\u{feff}').trim();
    if text.starts_with('+') {
        // PROJ.4: one line of `+key=value` pairs.
        let definition = text.split_whitespace().collect::<Vec<_>>().join(" ");
        let geographic =
            ["+proj=longlat", "+proj=latlong", "+proj=lonlat", "+proj=latlon"].iter().any(|p| definition.contains(p));
        let crs = if geographic { Crs::Geographic { epsg: None } } else { Crs::Projected { epsg: None } };
        return (crs, Some(definition));
    }
    let Some(node) = parse(text) else {
        return (Crs::Projected { epsg: None }, None);
    };
    let node = horizontal(&node);
    let epsg = node
        .children
        .iter()
        .rev()
        .find(|c| matches!(c.keyword.as_str(), "AUTHORITY" | "ID"))
        .filter(|c| c.values.first().is_some_and(|v| v.eq_ignore_ascii_case("EPSG")))
        .and_then(|c| c.values.get(1))
        .and_then(|v| v.parse::<u32>().ok());
    let geographic = matches!(node.keyword.as_str(), "GEOGCS" | "GEOGCRS" | "GEOGRAPHICCRS");
    let crs = if geographic { Crs::Geographic { epsg } } else { Crs::Projected { epsg } };
    (crs, None)
}

/// A compound CRS's horizontal part (its first CRS), or the CRS itself.
fn horizontal(node: &Node) -> &Node {
    if matches!(node.keyword.as_str(), "COMPD_CS" | "COMPOUNDCRS") {
        let crs = ["PROJCS", "GEOGCS", "PROJCRS", "GEOGCRS", "PROJECTEDCRS", "GEOGRAPHICCRS"];
        if let Some(child) = node.children.iter().find(|c| crs.contains(&c.keyword.as_str())) {
            return child;
        }
    }
    node
}

/// A WKT node: `KEYWORD[value, "text", CHILD[...], ...]`.
#[derive(Debug, Default)]
struct Node {
    /// Upper case.
    keyword: String,
    /// Numbers and quoted texts (unquoted), in order.
    values: Vec<String>,
    children: Vec<Node>,
}

/// The first WKT node of `text`; `None` if it is not WKT.
fn parse(text: &str) -> Option<Node> {
    let chars: Vec<char> = text.chars().collect();
    let mut at = 0;
    let node = node(&chars, &mut at, 0)?;
    Some(node)
}

/// The most nesting a `.prj` may have: real ones stay under 10.
const MAX_DEPTH: usize = 32;

fn node(s: &[char], at: &mut usize, depth: usize) -> Option<Node> {
    if depth > MAX_DEPTH {
        return None;
    }
    skip_space(s, at);
    let start = *at;
    while *at < s.len() && (s[*at].is_ascii_alphanumeric() || s[*at] == '_') {
        *at += 1;
    }
    let keyword: String = s[start..*at].iter().collect::<String>().to_ascii_uppercase();
    skip_space(s, at);
    if keyword.is_empty() || !matches!(s.get(*at), Some('[' | '(')) {
        return None;
    }
    *at += 1;
    let mut n = Node { keyword, ..Node::default() };
    loop {
        skip_space(s, at);
        match s.get(*at)? {
            ']' | ')' => {
                *at += 1;
                return Some(n);
            }
            ',' => *at += 1,
            '"' => {
                *at += 1;
                let mut v = String::new();
                loop {
                    match s.get(*at)? {
                        // WKT escapes a quote by doubling it.
                        '"' if s.get(*at + 1) == Some(&'"') => {
                            v.push('"');
                            *at += 2;
                        }
                        '"' => {
                            *at += 1;
                            break;
                        }
                        c => {
                            v.push(*c);
                            *at += 1;
                        }
                    }
                }
                n.values.push(v);
            }
            c if c.is_ascii_alphabetic() => {
                // A child node, or a bare word (an axis direction: NORTH).
                let save = *at;
                match node(s, at, depth + 1) {
                    Some(child) => n.children.push(child),
                    None => {
                        *at = save;
                        let v = word(s, at);
                        n.values.push(v);
                    }
                }
            }
            _ => {
                let v = word(s, at);
                if v.is_empty() {
                    return None;
                }
                n.values.push(v);
            }
        }
    }
}

fn word(s: &[char], at: &mut usize) -> String {
    let start = *at;
    while *at < s.len() && !matches!(s[*at], ',' | ']' | ')' | '[' | '(' | '"') && !s[*at].is_whitespace() {
        *at += 1;
    }
    s[start..*at].iter().collect()
}

fn skip_space(s: &[char], at: &mut usize) {
    while *at < s.len() && s[*at].is_whitespace() {
        *at += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wkt1_projected_crs_gives_its_own_code_not_its_datum_s() {
        let wkt = r#"PROJCS["RGF93 / Lambert-93",GEOGCS["RGF93",DATUM["Reseau_Geodesique_Francais_1993",
            SPHEROID["GRS 1980",6378137,298.257222101,AUTHORITY["EPSG","7019"]],AUTHORITY["EPSG","6171"]],
            PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433],
            AUTHORITY["EPSG","4171"]],PROJECTION["Lambert_Conformal_Conic_2SP"],
            PARAMETER["standard_parallel_1",49],UNIT["metre",1,AUTHORITY["EPSG","9001"]],
            AXIS["X",EAST],AXIS["Y",NORTH],AUTHORITY["EPSG","2154"]]"#;
        assert_eq!(crs_of_prj(wkt), (Crs::Projected { epsg: Some(2154) }, None));
    }

    #[test]
    fn wkt2_geographic_and_compound_crs() {
        let wkt2 = r#"GEOGCRS["WGS 84",DATUM["World Geodetic System 1984",ELLIPSOID["WGS 84",6378137,298.257223563,
            LENGTHUNIT["metre",1]]],CS[ellipsoidal,2],AXIS["latitude",north],ID["EPSG",4326]]"#;
        assert_eq!(crs_of_prj(wkt2), (Crs::Geographic { epsg: Some(4326) }, None));
        let compound = r#"COMPD_CS["OSGB36 / British National Grid + ODN",PROJCS["OSGB 1936 / British National Grid",
            GEOGCS["OSGB 1936",AUTHORITY["EPSG","4277"]],AUTHORITY["EPSG","27700"]],
            VERT_CS["Newlyn",AUTHORITY["EPSG","5701"]],AUTHORITY["EPSG","7405"]]"#;
        assert_eq!(crs_of_prj(compound), (Crs::Projected { epsg: Some(27700) }, None));
    }

    #[test]
    fn esri_wkt_without_a_code_keeps_its_kind() {
        let esri = r#"PROJCS["NAD_1983_UTM_Zone_10N",GEOGCS["GCS_North_American_1983",DATUM["D_North_American_1983",
            SPHEROID["GRS_1980",6378137.0,298.257222101]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],
            PROJECTION["Transverse_Mercator"],PARAMETER["False_Easting",500000.0],UNIT["Meter",1.0]]"#;
        assert_eq!(crs_of_prj(esri), (Crs::Projected { epsg: None }, None));
        let geographic = r#"GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137,298.257223563]],
            PRIMEM["Greenwich",0],UNIT["Degree",0.017453292519943295]]"#;
        assert_eq!(crs_of_prj(geographic), (Crs::Geographic { epsg: None }, None));
    }

    #[test]
    fn a_proj4_string_is_kept_as_it_stands() {
        let (crs, def) = crs_of_prj("+proj=lcc +lat_1=49 +lat_2=44 +lat_0=46.5 +lon_0=3\n +x_0=700000 +ellps=GRS80\n");
        assert_eq!(crs, Crs::Projected { epsg: None });
        assert_eq!(def.as_deref(), Some("+proj=lcc +lat_1=49 +lat_2=44 +lat_0=46.5 +lon_0=3 +x_0=700000 +ellps=GRS80"));
        assert_eq!(crs_of_prj("+proj=longlat +datum=WGS84").0, Crs::Geographic { epsg: None });
    }

    #[test]
    fn text_that_is_not_wkt_names_nothing() {
        for text in ["", "hello", "PROJCS[", "PROJCS[\"unclosed", &"A[".repeat(100), "]]]", "PROJCS[1,,]"] {
            assert_eq!(crs_of_prj(text), (Crs::Projected { epsg: None }, None), "{text}");
        }
    }
}
