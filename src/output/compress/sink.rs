//! The binary chunk and its JSON arrays as a .glb is built: what the
//! layout fills and the meshopt codec packs.

use serde_json::Value;

/// The binary chunk and the JSON arrays that describe it, as a .glb is
/// built; `streams` lists the bufferViews `meshopt` compresses.
#[derive(Default)]
pub struct Sink {
    /// The binary chunk so far.
    pub bin: Vec<u8>,
    /// `bufferViews`.
    pub views: Vec<Value>,
    /// `accessors`.
    pub accessors: Vec<Value>,
    /// Vertex and index streams, for [`meshopt_pack`].
    pub streams: Vec<Stream>,
}

/// A bufferView of vertex or index data.
pub struct Stream {
    pub(super) view: usize,
    pub(super) count: usize,
    pub(super) stride: usize,
    /// Index data (u16 or u32 triangles) rather than vertex attributes.
    pub(super) triangles: bool,
    /// Vertices the indices refer to (index streams only).
    pub(super) vertices: usize,
    /// What `meshopt` encodes instead, and the filter (OCTAHEDRAL or
    /// EXPONENTIAL) that decodes it into the bytes written.
    pub(super) filtered: Option<(&'static str, Vec<u8>)>,
}

/// Pads `bin` with zeros to a multiple of 4 bytes, as glTF aligns bufferViews.
pub fn align4(bin: &mut Vec<u8>) {
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
}
