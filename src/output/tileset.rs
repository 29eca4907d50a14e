//! Write the index: a 3D Tiles 1.1 `tileset.json` over the chunk tree.
//!
//! glTF content is y-up; 3D Tiles is z-up and rotates y-up glTF by +90° about
//! x when loading it (3D Tiles 1.1, "glTF transforms"), so a world point
//! (x, y, z) of a chunk sits at (x, −z, y) in tileset coordinates: east,
//! north, up. Bounding boxes are given in that frame. For a georeferenced
//! grid whose CRS `geodesy` can invert, the root carries a `transform` that
//! puts that frame on the WGS 84 globe (the east-north-up frame at the grid
//! centre; `extras.terrachunk.placement` says where and how); other grids
//! have none and stay in their local frame. What 3D Tiles does not
//! carry (levels, morph, skirts, τ_max, texture sizing) goes into `extras.terrachunk`, whose
//! shape is the types below and whose JSON Schemas in `schemas/` are
//! generated from them.

use std::path::{Path, PathBuf};

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use serde_json::json;

use crate::geodesy::Placement;
use crate::heightfield::Georef;
use crate::quadtree::{ChunkKey, ChunkTree};
use crate::texture::TextureExtras;

/// `extras.terrachunk` on the tileset: what a client needs beyond 3D Tiles.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TilesetExtras {
    /// terrachunk version that wrote the tileset.
    pub generator: String,
    /// Source grid size in samples.
    pub grid: GridSize,
    /// Ground distance between samples, metres: `[s_x, s_z]`.
    pub spacing_m: [f64; 2],
    /// Height multiplier applied on load (1 = the file's metres).
    pub vertical_scale: f64,
    /// δ of the deepest level, metres (the user's accuracy target).
    pub max_error_m: f64,
    /// Largest screen-space error, pixels, the runtime may use.
    pub tau_max_px: f64,
    /// Number of levels the tree may have (deepest level + 1).
    pub levels: u32,
    /// δ(L) for every level, metres; each half the one before.
    pub delta_m: Vec<f64>,
    /// The DEM file(s) read, by name and content (never by folder, so the
    /// same DEM gives the same bytes from anywhere): `verify` finds them
    /// by name beside the tileset and uses one only if its content matches.
    pub source: Vec<SourceFile>,
    /// The geoid model whose undulation was added to the DEM's heights
    /// (`--geoid`), by name and content as `source`; absent: the heights
    /// are the DEM's as given, taken as ellipsoidal.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geoid: Option<SourceFile>,
    /// Georeference of the source, and the local tangent plane if geographic.
    pub georef: Georef,
    /// Where the root `transform` puts the grid on the WGS 84 globe (absent
    /// when the CRS is unknown or not one terrachunk can invert; the
    /// tileset then has no transform).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub placement: Option<Placement>,
    /// How to read the morph targets.
    pub morph: MorphConvention,
    /// How deep the skirts hang.
    pub skirt: String,
    /// How the texture tiles were made and what bounds them (absent when
    /// the chunks are untextured).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture: Option<TextureExtras>,
}

/// One DEM file a tileset was built from.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SourceFile {
    /// The file's name, without its folder.
    pub name: String,
    /// Its length, bytes.
    pub bytes: u64,
    /// SHA-256 of its content, 64 lowercase hexadecimal digits.
    pub sha256: String,
}

impl SourceFile {
    /// Names, lengths and hashes of the files `inputs` name, as the
    /// loader reads them: a folder stands for the `.hgt` tiles in it, in
    /// name order. Errors name the file that could not be read.
    pub fn of_inputs(inputs: &[PathBuf]) -> Result<Vec<SourceFile>, (PathBuf, std::io::Error)> {
        let mut files = Vec::new();
        for input in inputs {
            if input.is_dir() {
                let mut tiles = Vec::new();
                for entry in std::fs::read_dir(input).map_err(|e| (input.clone(), e))? {
                    let p = entry.map_err(|e| (input.clone(), e))?.path();
                    if crate::dem::is_hgt(&p) && p.is_file() {
                        tiles.push(p);
                    }
                }
                tiles.sort();
                files.extend(tiles);
            } else {
                files.push(input.clone());
            }
        }
        files.iter().map(|p| SourceFile::of(p).map_err(|e| (p.clone(), e))).collect()
    }

    /// The name, length and hash of the file at `path`, read in pieces.
    pub fn of(path: &Path) -> std::io::Result<SourceFile> {
        let (bytes, sha256) = sha256_of(std::fs::File::open(path)?)?;
        let name = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
        Ok(SourceFile { name, bytes, sha256 })
    }
}

/// The length and SHA-256 (lowercase hex) of everything `r` yields, read
/// in pieces: memory does not grow with the file.
pub fn sha256_of(mut r: impl std::io::Read) -> std::io::Result<(u64, String)> {
    use sha2::Digest;
    let mut hasher = sha2::Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut total = 0u64;
    loop {
        let n = r.read(&mut buf)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
        total += n as u64;
    }
    Ok((total, format!("{:x}", hasher.finalize())))
}

/// Grid size in samples.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct GridSize {
    /// Samples per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

/// The morph-target convention of every chunk.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MorphConvention {
    /// Name of the morph target (also in `mesh.extras.targetNames`).
    pub target: String,
    /// What the target holds.
    pub delta: String,
    /// The blend schedule that keeps the screen error bound, and its guarantee.
    pub schedule: String,
}

/// `extras.terrachunk` on every tile.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TileExtras {
    /// Level, 0 = top.
    pub level: u32,
    /// Column among the level's chunks (east).
    pub x: u32,
    /// Row among the level's chunks (south).
    pub y: u32,
    /// δ(L), metres; also the tile's geometricError.
    pub delta_m: f64,
}

/// One written chunk, as the index needs it.
#[derive(Clone, Debug)]
pub struct TileRecord {
    /// Which chunk.
    pub key: ChunkKey,
    /// World-space box (glTF frame, metres): min and max corners.
    pub min: [f64; 3],
    /// Max corner.
    pub max: [f64; 3],
    /// δ(L).
    pub delta_m: f64,
}

/// Path of a chunk's file relative to the tileset root.
pub fn tile_uri(k: ChunkKey) -> String {
    format!("tiles/{}/{}/{}.glb", k.level, k.x, k.y)
}

/// 3D Tiles box (z-up frame) for a glTF-frame world box.
pub fn tiles_box(min: [f64; 3], max: [f64; 3]) -> [f64; 12] {
    let c = [0, 1, 2].map(|a| (min[a] + max[a]) / 2.0);
    let h = [0, 1, 2].map(|a| ((max[a] - min[a]) / 2.0).max(1e-3));
    [c[0], -c[2], c[1], h[0], 0.0, 0.0, 0.0, h[2], 0.0, 0.0, 0.0, h[1]]
}

/// The `tileset.json` document over `records` (sorted by key), to
/// serialize, and the external tilesets it refers to
/// ([`TilesetDoc::external`]) where it has more than `max_tiles` tiles. It
/// is written as it is walked, never held as a JSON tree: a tree of 45 000
/// tiles took 250 MB, more than the grid itself. Keys come in sorted order,
/// as a `serde_json::Value` holds them.
pub fn tileset_json<'a>(
    tree: &'a ChunkTree,
    records: &'a [TileRecord],
    extras: &'a TilesetExtras,
    max_tiles: usize,
) -> TilesetDoc<'a> {
    // Each tile's box holds its children's, and its count theirs: bottom-up
    // over the records, deepest level first.
    let mut boxes: Vec<([f64; 3], [f64; 3])> = records.iter().map(|r| (r.min, r.max)).collect();
    let mut counts = vec![1usize; records.len()];
    let mut order: Vec<usize> = (0..records.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(records[i].key.level));
    for i in order {
        let Some(p) = tree.parent(records[i].key).and_then(|k| find(records, k)) else { continue };
        let (lo, hi) = boxes[i];
        for a in 0..3 {
            boxes[p].0[a] = boxes[p].0[a].min(lo[a]);
            boxes[p].1[a] = boxes[p].1[a].max(hi[a]);
        }
        counts[p] += counts[i];
    }
    let tops: Vec<usize> = tree.roots().into_iter().filter_map(|k| find(records, k)).collect();
    let split = split_level(records, &counts, max_tiles);
    TilesetDoc { tree, records, extras, boxes, tops, split }
}

/// The shallowest level whose every tile heads a subtree of at most
/// `max_tiles` tiles (`counts`, per record), where the whole tree has more:
/// each of its tiles then goes into an external tileset of its own, and
/// `tileset.json` keeps the levels above. The rule reads the tree alone, so
/// a sharded build's merge splits the index as the whole build does.
fn split_level(records: &[TileRecord], counts: &[usize], max_tiles: usize) -> Option<u32> {
    if records.len() <= max_tiles {
        return None;
    }
    let deepest = records.iter().map(|r| r.key.level).max()?;
    (1..=deepest)
        .find(|&level| records.iter().zip(counts).filter(|(r, _)| r.key.level == level).all(|(_, &n)| n <= max_tiles))
}

fn find(records: &[TileRecord], k: ChunkKey) -> Option<usize> {
    records.binary_search_by(|r| r.key.cmp(&k)).ok()
}

/// [`tileset_json`]'s document.
pub struct TilesetDoc<'a> {
    tree: &'a ChunkTree,
    records: &'a [TileRecord],
    extras: &'a TilesetExtras,
    /// Per record, its box with all its descendants'.
    boxes: Vec<([f64; 3], [f64; 3])>,
    /// The records of the top-level chunks.
    tops: Vec<usize>,
    /// The level whose tiles head external tilesets ([`split_level`]).
    split: Option<u32>,
}

/// What [`write_index`] wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct IndexWritten {
    /// Bytes, all files together.
    pub bytes: u64,
    /// Files: `tileset.json` and its external tilesets.
    pub files: usize,
}

/// Writes `doc` as `dir/tileset.json` and its external tilesets beside it,
/// compact (a client reads a whole index file before it draws anything,
/// and indentation was four fifths of it; `jq .` reads them).
pub fn write_index(dir: &Path, doc: &TilesetDoc) -> Result<IndexWritten, (PathBuf, std::io::Error)> {
    let mut written = IndexWritten::default();
    let mut write = |name: &str, bytes: Vec<u8>| {
        let path = dir.join(name);
        std::fs::write(&path, &bytes).map_err(|e| (path, e))?;
        written.bytes += bytes.len() as u64;
        written.files += 1;
        Ok(())
    };
    for (uri, ext) in doc.external() {
        write(&uri, serde_json::to_vec(&ext).expect("JSON of plain values"))?;
    }
    write("tileset.json", serde_json::to_vec(doc).expect("JSON of plain values"))?;
    Ok(written)
}

/// Where the external tileset headed by chunk `k` lives, relative to the
/// tileset root: beside `tileset.json`, so that the content URIs inside it
/// (relative to it, as 3D Tiles reads them) are the same as in the root.
pub fn external_uri(k: ChunkKey) -> String {
    format!("tileset-{}-{}-{}.json", k.level, k.x, k.y)
}

/// An external tileset: the subtree under one chunk.
pub struct ExternalDoc<'d, 'a> {
    doc: &'d TilesetDoc<'a>,
    i: usize,
}

impl Serialize for ExternalDoc<'_, '_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut m = s.serialize_map(Some(3))?;
        m.serialize_entry("asset", &json!({"version": "1.1", "generator": self.doc.extras.generator}))?;
        m.serialize_entry("geometricError", &self.doc.reference_error(self.i))?;
        m.serialize_entry("root", &Tile { doc: self.doc, i: self.i, transform: None, heads_file: true })?;
        m.end()
    }
}

impl TilesetDoc<'_> {
    /// The box over every top-level chunk.
    fn whole_box(&self) -> ([f64; 3], [f64; 3]) {
        self.tops.iter().fold(([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]), |(mut lo, mut hi), &t| {
            let (l, h) = self.boxes[t];
            for a in 0..3 {
                lo[a] = lo[a].min(l[a]);
                hi[a] = hi[a].max(h[a]);
            }
            (lo, hi)
        })
    }

    fn children(&self, i: usize) -> Vec<usize> {
        self.tree.children(self.records[i].key).into_iter().filter_map(|c| find(self.records, c)).collect()
    }

    /// The external tilesets `tileset.json` refers to, in key order: their
    /// URIs ([`external_uri`]) and documents.
    pub fn external(&self) -> Vec<(String, ExternalDoc<'_, '_>)> {
        let Some(level) = self.split else { return Vec::new() };
        (0..self.records.len())
            .filter(|&i| self.records[i].key.level == level)
            .map(|i| (external_uri(self.records[i].key), ExternalDoc { doc: self, i }))
            .collect()
    }

    /// The geometric error of the tile that refers to the external tileset
    /// headed by record `i`, and of that tileset: its parent's δ, so that a
    /// client that judges the reference at all refines into it exactly
    /// where it refines the parent (the split level is never a top level).
    fn reference_error(&self, i: usize) -> f64 {
        let key = self.records[i].key;
        self.tree
            .parent(key)
            .and_then(|p| find(self.records, p))
            .map_or(self.records[i].delta_m, |p| self.records[p].delta_m)
    }
}

impl Serialize for TilesetDoc<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let (lo, hi) = self.whole_box();
        let whole = (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>().sqrt();
        let mut m = s.serialize_map(Some(4))?;
        m.serialize_entry("asset", &json!({"version": "1.1", "generator": self.extras.generator}))?;
        m.serialize_entry("extras", &json!({"terrachunk": self.extras}))?;
        m.serialize_entry("geometricError", &whole.max(4.0 * self.tree.delta_m[0]))?;
        let transform = self.extras.placement.as_ref().map(Placement::transform);
        // The error of drawing nothing at all is the whole terrain, not a level's
        // δ: 3D Tiles clients skip a tileset (or stop at a content-less tile)
        // whose error is below their bound on screen, so a terrain tileset
        // claiming 4·δ(0) vanished a few kilometres away in CesiumJS. The box's
        // diagonal keeps it drawn until the whole tileset is smaller than the
        // bound in pixels.
        match self.tops[..] {
            [top] => m.serialize_entry("root", &Tile { doc: self, i: top, transform, heads_file: true })?,
            _ => m.serialize_entry(
                "root",
                &Group { doc: self, lo, hi, error: whole.max(2.0 * self.tree.delta_m[0]), transform },
            )?,
        }
        m.end()
    }
}

/// One tile and, nested, its descendants; or, where it heads an external
/// tileset and is not that file's root, the tile that refers to it.
struct Tile<'d, 'a> {
    doc: &'d TilesetDoc<'a>,
    i: usize,
    transform: Option<[f64; 16]>,
    /// The root of the file being written.
    heads_file: bool,
}

impl Serialize for Tile<'_, '_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let r = &self.doc.records[self.i];
        let (lo, hi) = self.doc.boxes[self.i];
        let mut m = s.serialize_map(None)?;
        m.serialize_entry("boundingVolume", &json!({"box": tiles_box(lo, hi)}))?;
        if !self.heads_file && self.doc.split == Some(r.key.level) {
            // 3D Tiles: a tile whose content is a tileset has no children.
            m.serialize_entry("content", &json!({"uri": external_uri(r.key)}))?;
            m.serialize_entry("geometricError", &self.doc.reference_error(self.i))?;
            m.serialize_entry("refine", "REPLACE")?;
            return m.end();
        }
        let children = self.doc.children(self.i);
        if !children.is_empty() {
            let kids: Vec<Tile> =
                children.into_iter().map(|i| Tile { doc: self.doc, i, transform: None, heads_file: false }).collect();
            m.serialize_entry("children", &kids)?;
        }
        m.serialize_entry("content", &json!({"uri": tile_uri(r.key)}))?;
        let extras = TileExtras { level: r.key.level, x: r.key.x, y: r.key.y, delta_m: r.delta_m };
        m.serialize_entry("extras", &json!({"terrachunk": extras}))?;
        m.serialize_entry("geometricError", &r.delta_m)?;
        m.serialize_entry("refine", "REPLACE")?;
        if let Some(t) = &self.transform {
            m.serialize_entry("transform", t)?;
        }
        m.end()
    }
}

/// A non-square grid's root: content-less over its near-square cells (it
/// must always refine into them: see `whole` above).
struct Group<'d, 'a> {
    doc: &'d TilesetDoc<'a>,
    lo: [f64; 3],
    hi: [f64; 3],
    error: f64,
    transform: Option<[f64; 16]>,
}

impl Serialize for Group<'_, '_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut m = s.serialize_map(None)?;
        m.serialize_entry("boundingVolume", &json!({"box": tiles_box(self.lo, self.hi)}))?;
        let tops: Vec<Tile> =
            self.doc.tops.iter().map(|&i| Tile { doc: self.doc, i, transform: None, heads_file: false }).collect();
        m.serialize_entry("children", &tops)?;
        m.serialize_entry("geometricError", &self.error)?;
        m.serialize_entry("refine", "REPLACE")?;
        if let Some(t) = &self.transform {
            m.serialize_entry("transform", t)?;
        }
        m.end()
    }
}

/// The JSON Schemas of the extras, as `(file name, pretty JSON)`.
pub fn extras_schemas() -> Vec<(&'static str, String)> {
    let pretty = |s: schemars::Schema| serde_json::to_string_pretty(&s).expect("schema is JSON") + "\n";
    vec![
        ("tileset-extras.schema.json", pretty(schemars::schema_for!(TilesetExtras))),
        ("tile-extras.schema.json", pretty(schemars::schema_for!(TileExtras))),
    ]
}
