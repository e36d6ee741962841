//! Fixed-radius neighbour search with cell lists, in 1D, 2D and 3D, periodic or bounded.
//!
//! [`CellList::build`] puts every particle into a cell of edge `>= radius`
//! (`floor((x - lo) / cell)`, clamped into a bounded domain, wrapped in a periodic one), then
//! sorts particles by cell key with a counting sort (one histogram, one prefix sum, one scatter:
//! `O(N + cells)`) and keeps a copy of the positions in that order, so that a query streams
//! through the `3^d` neighbouring cells contiguously. [`CellList::query`] writes all pairs with
//! `|x_i - x_j| < radius` (minimum image in periodic directions), `j != i`, as a CSR
//! [`NeighborList`], in parallel over particles (rayon). All buffers (keys, sort, per-chunk
//! lists, the CSR arrays) are kept and reused by the next build, so a per-step rebuild does not
//! allocate once sizes have settled.
//!
//! Clamping is monotone and moves cell indices by at most as much as the positions, so particles
//! slightly outside a bounded domain are still found correctly (they collect in the edge cells).
//!
//! ```
//! use pbdl_particles::neighbors::{CellList, Domain, NeighborList};
//! let domain = Domain::periodic([0.0f64, 0.0], [1.0, 1.0]);
//! let pos = vec![[0.05, 0.5], [0.95, 0.5], [0.5, 0.5]];
//! let mut cells = CellList::new(domain, 0.2)?;
//! let mut nl = NeighborList::default();
//! cells.neighbors(&pos, &mut nl)?;
//! assert_eq!(nl.neighbors(0), &[1]); // across the periodic boundary
//! assert!(nl.neighbors(2).is_empty());
//! # Ok::<(), pbdl_particles::Error>(())
//! ```

use crate::error::{Error, Result};
use pbdl_core::Real;
use rayon::prelude::*;

/// Particles per parallel work item of a query.
const CHUNK: usize = 1024;
/// The largest number of cells a cell list may have.
const MAX_CELLS: usize = 1 << 28;

/// An axis-aligned box, periodic or bounded per direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Domain<T: Real, const D: usize> {
    /// Lower corner.
    pub lo: [T; D],
    /// Upper corner.
    pub hi: [T; D],
    /// Periodic directions.
    pub periodic: [bool; D],
}

impl<T: Real, const D: usize> Domain<T, D> {
    /// A box bounded in every direction.
    pub fn bounded(lo: [T; D], hi: [T; D]) -> Self {
        Domain { lo, hi, periodic: [false; D] }
    }

    /// A box periodic in every direction.
    pub fn periodic(lo: [T; D], hi: [T; D]) -> Self {
        Domain { lo, hi, periodic: [true; D] }
    }

    /// Edge lengths.
    pub fn extent(&self) -> [T; D] {
        std::array::from_fn(|d| self.hi[d] - self.lo[d])
    }

    /// Checks the box: finite corners with `hi > lo`.
    pub fn validate(&self) -> Result<()> {
        for d in 0..D {
            let (lo, hi) = (self.lo[d].to_f64(), self.hi[d].to_f64());
            if !(lo.is_finite() && hi.is_finite() && hi > lo) {
                return Err(Error::invalid(
                    "domain",
                    format!("direction {d}: lo = {lo}, hi = {hi}; need finite lo < hi"),
                ));
            }
        }
        Ok(())
    }

    /// The position wrapped into the box in periodic directions (unchanged elsewhere).
    #[inline]
    pub fn wrap(&self, mut x: [T; D]) -> [T; D] {
        for d in 0..D {
            if self.periodic[d] {
                let l = self.hi[d] - self.lo[d];
                let mut y = x[d] - self.lo[d];
                if y < T::zero() || y >= l {
                    y -= (y / l).floor() * l;
                    if y >= l {
                        y -= l;
                    }
                }
                x[d] = self.lo[d] + y;
            }
        }
        x
    }

    /// `b - a` with the minimum-image convention in periodic directions (positions in the box).
    #[inline]
    pub fn displacement(&self, a: &[T; D], b: &[T; D]) -> [T; D] {
        std::array::from_fn(|d| {
            let mut x = b[d] - a[d];
            if self.periodic[d] {
                let l = self.hi[d] - self.lo[d];
                let half = l * T::c(0.5);
                if x > half {
                    x -= l;
                } else if x < -half {
                    x += l;
                }
            }
            x
        })
    }
}

/// Neighbour lists in compressed sparse row form: the neighbours of particle `i` are
/// `indices[offsets[i]..offsets[i + 1]]` (not sorted, `i` itself excluded).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct NeighborList {
    /// `n + 1` row offsets.
    pub offsets: Vec<usize>,
    /// Neighbour indices, row after row.
    pub indices: Vec<u32>,
}

impl NeighborList {
    /// Number of particles (rows).
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Whether there are no particles.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The neighbours of particle `i`.
    #[inline]
    pub fn neighbors(&self, i: usize) -> &[u32] {
        &self.indices[self.offsets[i]..self.offsets[i + 1]]
    }

    /// Total number of (directed) entries, twice the number of pairs.
    pub fn num_entries(&self) -> usize {
        self.indices.len()
    }

    /// The unordered pairs `(i, j)`, `i < j`, written into `out` (cleared first), row by row.
    pub fn pairs_into(&self, out: &mut Vec<(u32, u32)>) {
        out.clear();
        for i in 0..self.len() {
            out.extend(self.neighbors(i).iter().filter(|&&j| (j as usize) > i).map(|&j| (i as u32, j)));
        }
    }

    /// The unordered pairs `(i, j)`, `i < j`.
    pub fn pairs(&self) -> Vec<(u32, u32)> {
        let mut v = Vec::with_capacity(self.indices.len() / 2);
        self.pairs_into(&mut v);
        v
    }

    /// Sorts every row (for comparisons and deterministic output).
    pub fn sort_rows(&mut self) {
        let offsets = &self.offsets;
        let mut rest: &mut [u32] = &mut self.indices;
        let mut rows = Vec::with_capacity(offsets.len());
        for i in 0..offsets.len().saturating_sub(1) {
            let (row, tail) = rest.split_at_mut(offsets[i + 1] - offsets[i]);
            rows.push(row);
            rest = tail;
        }
        rows.into_par_iter().for_each(|r| r.sort_unstable());
    }
}

/// A cell list over a [`Domain`] for a fixed search radius, with reusable buffers.
#[derive(Clone, Debug)]
pub struct CellList<T: Real, const D: usize> {
    domain: Domain<T, D>,
    radius: T,
    ncell: [usize; D],
    inv_cell: [T; D],
    /// Cell key of every particle (input order).
    keys: Vec<u32>,
    /// `cell_start[c]..cell_start[c + 1]` indexes `order` / `sorted` for cell `c`.
    cell_start: Vec<u32>,
    /// Particle indices sorted by cell.
    order: Vec<u32>,
    /// Wrapped positions sorted by cell.
    sorted: Vec<[T; D]>,
    /// Wrapped positions in input order.
    wrapped: Vec<[T; D]>,
    /// Per-chunk neighbour buffers of a query.
    chunks: Vec<Vec<u32>>,
}

impl<T: Real, const D: usize> CellList<T, D> {
    /// A cell list for `domain` and search `radius`.
    ///
    /// Errors: a bad domain, `radius <= 0`, a periodic direction shorter than `2 radius`
    /// (the minimum image would be ambiguous), or more than 2^28 cells.
    pub fn new(domain: Domain<T, D>, radius: T) -> Result<Self> {
        if !(1..=3).contains(&D) {
            return Err(Error::invalid("D", format!("{D}; cell lists exist in 1, 2 and 3 dimensions")));
        }
        domain.validate()?;
        let (ncell, inv_cell) = Self::geometry(&domain, radius)?;
        Ok(CellList {
            domain,
            radius,
            ncell,
            inv_cell,
            keys: Vec::new(),
            cell_start: Vec::new(),
            order: Vec::new(),
            sorted: Vec::new(),
            wrapped: Vec::new(),
            chunks: Vec::new(),
        })
    }

    fn geometry(domain: &Domain<T, D>, radius: T) -> Result<([usize; D], [T; D])> {
        let r = radius.to_f64();
        if !(r > 0.0 && r.is_finite()) {
            return Err(Error::invalid("radius", format!("{r}; the search radius must be positive and finite")));
        }
        let ext = domain.extent();
        let mut ncell = [1usize; D];
        let mut inv_cell = [T::one(); D];
        let mut total = 1usize;
        for d in 0..D {
            let l = ext[d].to_f64();
            if domain.periodic[d] && l < 2.0 * r {
                return Err(Error::invalid(
                    "radius",
                    format!("{r} is more than half the periodic length {l} in direction {d}; enlarge the box"),
                ));
            }
            // A hair below l / r so that float rounding never makes a cell shorter than the radius.
            let n = ((l / r * (1.0 - 1e-6)).floor() as usize).max(1);
            ncell[d] = n;
            inv_cell[d] = T::c(n as f64 / l);
            total = total.saturating_mul(n);
        }
        if total > MAX_CELLS {
            return Err(Error::invalid(
                "radius",
                format!("{r} gives {total} cells (at most {MAX_CELLS}); use a larger radius or a smaller domain"),
            ));
        }
        Ok((ncell, inv_cell))
    }

    /// Changes the search radius (same checks as [`CellList::new`]); buffers are kept.
    /// Call [`CellList::build`] again before querying.
    pub fn set_radius(&mut self, radius: T) -> Result<()> {
        let (ncell, inv_cell) = Self::geometry(&self.domain, radius)?;
        self.ncell = ncell;
        self.inv_cell = inv_cell;
        self.radius = radius;
        self.order.clear();
        self.keys.clear();
        self.cell_start.clear();
        Ok(())
    }

    /// The domain.
    pub fn domain(&self) -> &Domain<T, D> {
        &self.domain
    }

    /// The search radius.
    pub fn radius(&self) -> T {
        self.radius
    }

    /// Cells per direction.
    pub fn cells(&self) -> [usize; D] {
        self.ncell
    }

    /// Particle indices sorted by cell key (valid after [`CellList::build`]).
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    #[inline]
    fn cell_coords(&self, x: &[T; D]) -> [usize; D] {
        std::array::from_fn(|d| {
            let c = ((x[d] - self.domain.lo[d]) * self.inv_cell[d]).floor();
            // Saturating casts: NaN -> 0, negative -> 0; clamp the top.
            let c = c.to_f64().max(0.0) as usize;
            c.min(self.ncell[d] - 1)
        })
    }

    #[inline]
    fn key(&self, c: &[usize; D]) -> usize {
        let mut k = 0;
        for d in (0..D).rev() {
            k = k * self.ncell[d] + c[d];
        }
        k
    }

    /// Sorts `positions` into cells (counting sort on cell keys).
    ///
    /// Errors: more than `u32::MAX` particles.
    pub fn build(&mut self, positions: &[[T; D]]) -> Result<()> {
        let n = positions.len();
        if n >= u32::MAX as usize {
            return Err(Error::invalid("positions", format!("{n} particles; at most {} are supported", u32::MAX - 1)));
        }
        let ncells: usize = self.ncell.iter().product();
        let domain = self.domain;
        self.wrapped.resize(n, [T::zero(); D]);
        self.wrapped
            .par_iter_mut()
            .zip(positions.par_iter())
            .with_min_len(4096)
            .for_each(|(w, p)| *w = domain.wrap(*p));
        let mut keys = std::mem::take(&mut self.keys);
        keys.resize(n, 0);
        {
            let this = &*self;
            keys.par_iter_mut()
                .zip(this.wrapped.par_iter())
                .with_min_len(4096)
                .for_each(|(k, p)| *k = this.key(&this.cell_coords(p)) as u32);
        }
        self.keys = keys;
        // Counting sort: histogram, exclusive prefix sum, scatter.
        self.cell_start.clear();
        self.cell_start.resize(ncells + 1, 0);
        for &k in &self.keys {
            self.cell_start[k as usize + 1] += 1;
        }
        for c in 0..ncells {
            self.cell_start[c + 1] += self.cell_start[c];
        }
        self.order.resize(n, 0);
        self.sorted.resize(n, [T::zero(); D]);
        // Scatter with a running cursor per cell; `cell_start[c]` is restored afterwards.
        for (i, &k) in self.keys.iter().enumerate() {
            let slot = &mut self.cell_start[k as usize];
            self.order[*slot as usize] = i as u32;
            self.sorted[*slot as usize] = self.wrapped[i];
            *slot += 1;
        }
        for c in (1..=ncells).rev() {
            self.cell_start[c] = self.cell_start[c - 1];
        }
        self.cell_start[0] = 0;
        Ok(())
    }

    /// The neighbouring cells' coordinate candidates in direction `d` of cell coordinate `c`
    /// (`len` valid entries).
    #[inline]
    fn axis_cells(&self, d: usize, c: usize) -> ([usize; 3], usize) {
        let n = self.ncell[d];
        if self.domain.periodic[d] {
            match n {
                1 => ([0, 0, 0], 1),
                2 => ([0, 1, 0], 2),
                _ => ([(c + n - 1) % n, c, (c + 1) % n], 3),
            }
        } else {
            let mut out = [0; 3];
            let mut len = 0;
            if c > 0 {
                out[len] = c - 1;
                len += 1;
            }
            out[len] = c;
            len += 1;
            if c + 1 < n {
                out[len] = c + 1;
                len += 1;
            }
            (out, len)
        }
    }

    /// Calls `f(j, x_j - x_i)` for every neighbour `j != i` of the point `x` (index `i`, or
    /// `usize::MAX` for a point that is not a particle) within the radius (after a build).
    #[inline]
    pub fn for_each_near(&self, i: usize, x: &[T; D], mut f: impl FnMut(usize, [T; D])) {
        if self.cell_start.is_empty() {
            return;
        }
        let r2 = self.radius * self.radius;
        let x = self.domain.wrap(*x);
        let c = self.cell_coords(&x);
        // Direction 0 is the fastest in the key, so neighbouring cells along it are contiguous
        // in the sorted arrays: scan them as one or two runs instead of three cells.
        let n0 = self.ncell[0];
        let c0 = c[0];
        let mut runs = [(0usize, 0usize); 2];
        let nruns = if !self.domain.periodic[0] {
            runs[0] = (c0.saturating_sub(1), (c0 + 1).min(n0 - 1));
            1
        } else if n0 <= 3 {
            runs[0] = (0, n0 - 1);
            1
        } else if c0 == 0 {
            runs = [(n0 - 1, n0 - 1), (0, 1)];
            2
        } else if c0 == n0 - 1 {
            runs = [(n0 - 2, n0 - 1), (0, 0)];
            2
        } else {
            runs[0] = (c0 - 1, c0 + 1);
            1
        };
        let mut axes = [([0usize; 3], 1usize); D];
        for d in 1..D {
            axes[d] = self.axis_cells(d, c[d]);
        }
        let mut idx = [0usize; D];
        'cells: loop {
            let mut cc: [usize; D] = std::array::from_fn(|d| axes[d].0[idx[d]]);
            for &(a, b) in &runs[..nruns] {
                cc[0] = a;
                let s = self.cell_start[self.key(&cc)] as usize;
                cc[0] = b;
                let e = self.cell_start[self.key(&cc) + 1] as usize;
                for m in s..e {
                    let dx = self.domain.displacement(&x, &self.sorted[m]);
                    let d2 = dx.iter().fold(T::zero(), |a, &v| a + v * v);
                    if d2 < r2 {
                        let j = self.order[m] as usize;
                        if j != i {
                            f(j, dx);
                        }
                    }
                }
            }
            for d in 1..D {
                idx[d] += 1;
                if idx[d] < axes[d].1 {
                    continue 'cells;
                }
                idx[d] = 0;
            }
            break;
        }
    }

    /// Writes the neighbour lists of the particles of the last [`CellList::build`] into `out`
    /// (its buffers are reused).
    pub fn query(&mut self, out: &mut NeighborList) {
        self.query_first(self.order.len(), out);
    }

    /// Like [`CellList::query`], but lists only the neighbours of the first `n` particles (all
    /// particles are still candidates): `out` has `n` rows. For solvers whose other particles
    /// (e.g. fixed walls) need no list of their own.
    pub fn query_first(&mut self, n: usize, out: &mut NeighborList) {
        let n = n.min(self.order.len());
        let nchunks = n.div_ceil(CHUNK);
        let mut chunks = std::mem::take(&mut self.chunks);
        chunks.resize_with(nchunks, Vec::new);
        out.offsets.clear();
        out.offsets.resize(n + 1, 0);
        {
            let this = &*self;
            chunks.par_iter_mut().zip(out.offsets[1..].par_chunks_mut(CHUNK)).enumerate().for_each(
                |(ci, (buf, counts))| {
                    buf.clear();
                    let start = ci * CHUNK;
                    for (k, cnt) in counts.iter_mut().enumerate() {
                        let i = start + k;
                        let before = buf.len();
                        this.for_each_near(i, &this.wrapped[i], |j, _| buf.push(j as u32));
                        *cnt = buf.len() - before;
                    }
                },
            );
        }
        for i in 0..n {
            out.offsets[i + 1] += out.offsets[i];
        }
        out.indices.resize(out.offsets[n], 0);
        let mut rest: &mut [u32] = &mut out.indices;
        let mut dests = Vec::with_capacity(nchunks);
        for buf in &chunks {
            let (head, tail) = rest.split_at_mut(buf.len());
            dests.push(head);
            rest = tail;
        }
        dests.into_par_iter().zip(chunks.par_iter()).for_each(|(d, s)| d.copy_from_slice(s));
        self.chunks = chunks;
    }

    /// [`CellList::build`] then [`CellList::query`].
    pub fn neighbors(&mut self, positions: &[[T; D]], out: &mut NeighborList) -> Result<()> {
        self.build(positions)?;
        self.query(out);
        Ok(())
    }
}

/// The neighbour lists by testing all `N^2` pairs (reference for tests), rows sorted.
pub fn brute_force<T: Real, const D: usize>(domain: &Domain<T, D>, radius: T, positions: &[[T; D]]) -> NeighborList {
    let r2 = radius * radius;
    let wrapped: Vec<[T; D]> = positions.iter().map(|p| domain.wrap(*p)).collect();
    let rows: Vec<Vec<u32>> = (0..wrapped.len())
        .into_par_iter()
        .map(|i| {
            (0..wrapped.len())
                .filter(|&j| {
                    j != i && {
                        let dx = domain.displacement(&wrapped[i], &wrapped[j]);
                        dx.iter().fold(T::zero(), |a, &v| a + v * v) < r2
                    }
                })
                .map(|j| j as u32)
                .collect()
        })
        .collect();
    let mut nl = NeighborList { offsets: vec![0], indices: Vec::new() };
    for r in rows {
        nl.indices.extend_from_slice(&r);
        nl.offsets.push(nl.indices.len());
    }
    nl
}
