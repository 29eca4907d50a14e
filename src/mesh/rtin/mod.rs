//! Right-triangle bintree (RTIN) mesher: the binary triangle tree of the
//! seeds' own chunker (Lindstrom et al. 1996, as in `chunklod-demo-readme`;
//! the 4-8 mesh that martini also uses), with true errors.
//!
//! Every triangle is right-isosceles: a square of `c` cells is cut by one
//! diagonal (main where its column plus row index, in squares of `c`, is
//! even, else the other one), each half by the square's centre into four
//! triangles whose hypotenuses are the square's sides, and each of those by
//! its side's midpoint into two halves of the squares of `c/2`. So the
//! pattern depends only on a triangle's place, not on any chunk or grid,
//! and chunks whose footprints are squares of 2^k cells aligned to 2^k
//! ([`plan`]) are unions of its triangles.
//!
//! One bottom-up pass ([`Rtin::new`]) gives every vertex `m` the largest
//! *true* error of the triangles split at `m`: the maximum over every valid
//! sample a triangle covers of |plane − sample| (plus what its corners'
//! heights round by in quantized output), and the same of the vertices its
//! children are split at. A triangle is split where that exceeds δ, so a
//! mesh at δ keeps every sample within δ, the two triangles that share a
//! hypotenuse split together (no crack), and a mesh at a smaller δ refines
//! one at a larger δ (nesting). A chunk of level L is the mesh at δ(L) of
//! the triangles inside its square: same-level neighbours draw one border,
//! and each child vertex's morph target is its parent's surface exactly
//! (the midpoint of the parent triangle's edge it splits, interpolated).
//!
//! The grid need not be 2^k + 1 samples: a triangle reaching past the
//! grid's last column or row is always split, until each piece lies inside
//! the grid or outside it (pieces outside are dropped), so the grid's edge is
//! made of triangle edges. Nodata is handled as the greedy TIN does: errors
//! count valid samples only, a vertex on nodata takes the void fill, and a
//! triangle that covers no valid sample is not written.

mod chunk;
mod field;
mod plan;
#[cfg(test)]
mod tests;
mod tri;

pub use field::{Rtin, Sag};
pub use plan::{fitting_root, plan, square_side};
