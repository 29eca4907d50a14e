//! Compressed vertex data (`compress = "quantize" | "meshopt" |
//! "meshopt-v1"`): integer positions, normals, morph deltas and texture
//! coordinates by KHR_mesh_quantization, then optionally meshoptimizer's
//! vertex and index codecs by EXT_meshopt_compression or
//! KHR_meshopt_compression; and the reader that turns such a file back into
//! the plain f32 glTF that `verify` and `inspect` read. Sizes and the
//! choices behind them: docs/compression.md.
//!
//! - `quantize.rs`: **the grid.** Positions are u16 on a grid that is the
//!   same for every chunk of a level and aligned to the world, so two
//!   chunks round a shared vertex alike and their borders stay identical.
//!   Horizontally the step is the sample spacing / 2^k(L), k(L) the largest
//!   that fits the level's widest footprint in 65 535 steps and at most 8
//!   (`MAX_SHIFT`): every DEM sample is on the grid, and the mesher places
//!   the cut points (the one kind of vertex off the sample grid) on it
//!   ([`crate::mesh::decimate::ChunkSpec::cut_lattice`]). Vertically one
//!   step for the tileset, a power of two ≤ `max_error_m / 16`, doubled
//!   while the tallest chunk would need more than 65 535 steps; a relief
//!   needing a step above `max_error_m / 4` is refused. The node carries
//!   the dequantisation (`translation` and `scale`, a contract change for
//!   these modes only: world = translation + scale · POSITION). Each
//!   triangle is meshed to δ(L) less the most its corners' heights round by
//!   ([`crate::mesh::decimate::Targets::rounding`]), and
//!   [`Quantization::cut_error`] measures each chunk as written, so the
//!   pipeline meshes it again with a wider margin where that misses δ.
//! - `layout.rs`: **the bytes.** Morph deltas in whole height steps (i8 where
//!   the chunk's fit, else i16 or f32), normals i8 normalized as the
//!   OCTAHEDRAL filter decodes them, texture coordinates u16 normalized;
//!   the vertex attributes interleaved, the normals and the triangles in
//!   three bufferViews shared by surface and skirt, and no default values
//!   in the JSON.
//! - `codecs.rs`: **meshopt.** Every stream through meshoptimizer's codecs;
//!   `meshopt` (EXT, vertex codec 0) decodes to exactly the bytes
//!   `quantize` writes, and its files stay what they were for readers that
//!   know only the EXT extension. EXT_meshopt_compression is *required* and
//!   the fallback buffer holds no data: an uncompressed fallback would make
//!   the file larger than `quantize`'s. `meshopt-v1` (KHR, vertex codec 1
//!   at level 3) also picks each normal's nearest octahedral lattice point
//!   ([`NormalEncoding::Nearest`](crate::config::NormalEncoding)), leaves
//!   names and the default roughness out of the JSON, shares one vertex set
//!   between surface and skirt (the skirt's tops are surface vertices), and
//!   writes a chunk over 255 cells wide's POSITION as f32 step counts
//!   through the EXPONENTIAL filter. Its surface decodes to what `quantize`
//!   writes with `normal_bits = 8`, its skirt to the same triangles.
//! - `decoder.rs`: **the reader**, [`decompress`]: any of these files back to
//!   plain f32 glTF, with checked arithmetic (a meshopt stream may claim
//!   only so many times its bytes, since meshoptimizer allocates first and
//!   asserts).

mod codecs;
mod decoder;
mod layout;
mod quantize;
mod sink;

pub use codecs::{cosine, decode_stream, encode_vertex_stream, meshopt_pack, octahedral};
pub use decoder::{Decoded, decompress};
pub use layout::write_quantized;
pub use quantize::{Frame, Quantization, QuantizeError};
pub use sink::{Sink, Stream, align4};
