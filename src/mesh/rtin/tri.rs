//! The bintree's triangles by place alone: a triangle, where it splits,
//! and where it lies against the grid.

/// A vertex's place on the grid: column, row.
pub(super) type P = (u32, u32);

/// A bintree triangle: hypotenuse `a`–`b`, right angle at `r`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Tri {
    pub(super) a: P,
    pub(super) b: P,
    pub(super) r: P,
}

impl Tri {
    /// Where it is split (its hypotenuse's midpoint), if that is a sample.
    #[inline]
    pub(super) fn midpoint(&self) -> Option<P> {
        let (sx, sz) = (self.a.0 + self.b.0, self.a.1 + self.b.1);
        (sx.is_multiple_of(2) && sz.is_multiple_of(2)).then_some((sx / 2, sz / 2))
    }

    /// The two halves it splits into at `m`.
    #[inline]
    pub(super) fn children(&self, m: P) -> [Tri; 2] {
        [Tri { a: self.r, b: self.a, r: m }, Tri { a: self.b, b: self.r, r: m }]
    }

    /// Squared hypotenuse, in cells².
    #[inline]
    pub(super) fn hyp2(&self) -> u64 {
        let dx = u64::from(self.a.0.abs_diff(self.b.0));
        let dz = u64::from(self.a.1.abs_diff(self.b.1));
        dx * dx + dz * dz
    }

    /// Bounding box: (x0, x1, z0, z1).
    #[inline]
    pub(super) fn bbox(&self) -> (u32, u32, u32, u32) {
        let (a, b, r) = (self.a, self.b, self.r);
        (a.0.min(b.0).min(r.0), a.0.max(b.0).max(r.0), a.1.min(b.1).min(r.1), a.1.max(b.1).max(r.1))
    }
}

/// Where a triangle lies against the grid `[0, xmax] × [0, zmax]`.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(super) enum Place {
    Inside,
    /// Its box reaches past the grid's last column or row from inside:
    /// always split. (A box is a superset, so a few triangles that lie
    /// wholly outside are split too; that costs nothing the output keeps.)
    Straddles,
    Outside,
}

pub(super) fn place(t: &Tri, xmax: u32, zmax: u32) -> Place {
    let (x0, x1, z0, z1) = t.bbox();
    if x0 >= xmax || z0 >= zmax {
        Place::Outside
    } else if x1 > xmax || z1 > zmax {
        Place::Straddles
    } else {
        Place::Inside
    }
}

/// The two triangles of the square of side `c` at (x0, z0), with their
/// corners in `[a, b, r]` order.
pub(super) fn square_triangles(x0: u32, z0: u32, c: u32) -> [(Tri, [P; 3]); 2] {
    let (p00, p10, p01, p11) = ((x0, z0), (x0 + c, z0), (x0, z0 + c), (x0 + c, z0 + c));
    let tris = if ((x0 / c) + (z0 / c)).is_multiple_of(2) {
        [Tri { a: p00, b: p11, r: p01 }, Tri { a: p11, b: p00, r: p10 }]
    } else {
        [Tri { a: p10, b: p01, r: p00 }, Tri { a: p01, b: p10, r: p11 }]
    };
    tris.map(|t| (t, [t.a, t.b, t.r]))
}

/// The (one or two) triangles of the squares of `c` split at `m`: the
/// halves of the square centred there (`square`), or the two whose
/// hypotenuse is the side through it.
pub(super) fn split_at(c: u32, square: bool, m: P) -> [Option<Tri>; 2] {
    let h = c / 2;
    if square {
        // The square of side c centred at m, cut by its diagonal.
        let (x0, z0) = (m.0 - h, m.1 - h);
        square_triangles(x0, z0, c).map(|(t, _)| Some(t))
    } else if m.1.is_multiple_of(c) {
        // A horizontal side: apexes at the centres above and below.
        let (p, q) = ((m.0 - h, m.1), (m.0 + h, m.1));
        [m.1.checked_sub(h).map(|zu| Tri { a: q, b: p, r: (m.0, zu) }), Some(Tri { a: p, b: q, r: (m.0, m.1 + h) })]
    } else {
        let (p, q) = ((m.0, m.1 - h), (m.0, m.1 + h));
        [m.0.checked_sub(h).map(|xl| Tri { a: p, b: q, r: (xl, m.1) }), Some(Tri { a: q, b: p, r: (m.0 + h, m.1) })]
    }
}
