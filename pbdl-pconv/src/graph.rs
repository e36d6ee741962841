//! Who convolves with whom: [`PairGraph`], the receiver-sorted list of (receiver, sender) pairs
//! within the support radius, with the periodic image shift of each pair, and the
//! differentiable offsets `x_j - x_i` that the convolution consumes.
//!
//! The graph is structure, not data: it is rebuilt when particles move (one cell-list search),
//! while the offsets are a candle expression of the positions, so gradients reach positions.
//!
//! ```
//! use candle_core::{Device, Tensor};
//! use pbdl_pconv::graph::PairGraph;
//! use pbdl_particles::Domain;
//!
//! let x = [[0.0], [0.3], [0.9]];
//! let g = PairGraph::build_self(&Domain::periodic([0.0], [1.0]), 0.35, &x)?;
//! // 0-1 and (through the periodic boundary) 0-2 are neighbours; 1-2 are 0.6 apart.
//! assert_eq!(g.num_pairs(), 4);
//! let pos = Tensor::new(&[[0.0f64], [0.3], [0.9]], &Device::Cpu)?;
//! let d = g.offsets(&pos, &pos)?.flatten_all()?.to_vec1::<f64>()?;
//! assert!((d[1] - (-0.1)).abs() < 1e-12); // receiver 0, sender 2 seen at -0.1
//! # Ok::<(), pbdl_pconv::Error>(())
//! ```

use crate::error::{Error, Result};
use candle_core::{DType, Tensor};
use pbdl_particles::{CellList, Domain};

/// Pairs `(i, j)` with `|x_j - x_i| < R` (minimum image in periodic directions), sorted by
/// receiver `i`; a particle is never its own neighbour in a self graph.
#[derive(Clone, Debug, PartialEq)]
pub struct PairGraph {
    dim: usize,
    n_receivers: usize,
    n_senders: usize,
    radius: f64,
    self_graph: bool,
    /// `n_receivers + 1` offsets into the pair arrays.
    row_offsets: Vec<usize>,
    receivers: Vec<u32>,
    senders: Vec<u32>,
    /// Per pair, `dim` components: minimum-image offset minus the raw difference `x_j - x_i`.
    shifts: Vec<f64>,
    has_shifts: bool,
}

impl PairGraph {
    /// Pairs among one set of particles (senders = receivers), the particle itself excluded.
    pub fn build_self<const D: usize>(domain: &Domain<f64, D>, radius: f64, positions: &[[f64; D]]) -> Result<Self> {
        Self::search(domain, radius, positions, positions, true)
    }

    /// Pairs from `senders` (e.g. boundary particles) to `receivers`.
    pub fn build_cross<const D: usize>(
        domain: &Domain<f64, D>,
        radius: f64,
        receivers: &[[f64; D]],
        senders: &[[f64; D]],
    ) -> Result<Self> {
        Self::search(domain, radius, receivers, senders, false)
    }

    /// A bounded search box around all the given points (for scenes without a domain of their
    /// own): their bounding box grown by one radius.
    pub fn bounding_domain<const D: usize>(radius: f64, sets: &[&[[f64; D]]]) -> Result<Domain<f64, D>> {
        let mut lo = [f64::INFINITY; D];
        let mut hi = [f64::NEG_INFINITY; D];
        for p in sets.iter().flat_map(|s| s.iter()) {
            for d in 0..D {
                if !p[d].is_finite() {
                    return Err(Error::NonFinite { what: "position", detail: format!("{p:?}") });
                }
                lo[d] = lo[d].min(p[d]);
                hi[d] = hi[d].max(p[d]);
            }
        }
        if lo[0] > hi[0] {
            lo = [0.0; D];
            hi = [0.0; D];
        }
        Ok(Domain::bounded(std::array::from_fn(|d| lo[d] - radius), std::array::from_fn(|d| hi[d] + radius)))
    }

    fn search<const D: usize>(
        domain: &Domain<f64, D>,
        radius: f64,
        receivers: &[[f64; D]],
        senders: &[[f64; D]],
        self_graph: bool,
    ) -> Result<Self> {
        if !(radius > 0.0 && radius.is_finite()) {
            return Err(Error::Config { field: "radius", reason: format!("{radius}; must be positive and finite") });
        }
        for (what, set) in [("receiver position", receivers), ("sender position", senders)] {
            if let Some(p) = set.iter().find(|p| p.iter().any(|v| !v.is_finite())) {
                return Err(Error::NonFinite { what, detail: format!("{p:?}") });
            }
        }
        if senders.len() >= u32::MAX as usize || receivers.len() >= u32::MAX as usize {
            return Err(Error::Shape(format!("{} / {} particles; at most 2^32 - 2", receivers.len(), senders.len())));
        }
        let mut cells = CellList::new(*domain, radius)?;
        cells.build(senders)?;
        let mut row_offsets = Vec::with_capacity(receivers.len() + 1);
        row_offsets.push(0);
        let (mut rec, mut sen, mut shifts) = (Vec::new(), Vec::new(), Vec::new());
        let mut has_shifts = false;
        let mut row: Vec<(u32, [f64; D])> = Vec::new();
        for (i, x) in receivers.iter().enumerate() {
            row.clear();
            let me = if self_graph { i } else { usize::MAX };
            cells.for_each_near(me, x, |j, d| row.push((j as u32, d)));
            // Sender order within a row fixed by index, independent of the cell layout.
            row.sort_unstable_by_key(|&(j, _)| j);
            for &(j, d) in &row {
                rec.push(i as u32);
                sen.push(j);
                for a in 0..D {
                    let shift = d[a] - (senders[j as usize][a] - x[a]);
                    has_shifts |= shift != 0.0;
                    shifts.push(shift);
                }
            }
            row_offsets.push(sen.len());
        }
        Ok(PairGraph {
            dim: D,
            n_receivers: receivers.len(),
            n_senders: senders.len(),
            radius,
            self_graph,
            row_offsets,
            receivers: rec,
            senders: sen,
            shifts,
            has_shifts,
        })
    }

    /// Spatial dimension.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Number of receiving particles (output rows).
    pub fn n_receivers(&self) -> usize {
        self.n_receivers
    }

    /// Number of sending particles (feature rows).
    pub fn n_senders(&self) -> usize {
        self.n_senders
    }

    /// The search radius the graph was built with.
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// Whether senders and receivers are one set.
    pub fn is_self_graph(&self) -> bool {
        self.self_graph
    }

    /// Number of (directed) pairs.
    pub fn num_pairs(&self) -> usize {
        self.senders.len()
    }

    /// The pairs of receiver `i` are `row_offsets[i]..row_offsets[i + 1]`.
    pub fn row_offsets(&self) -> &[usize] {
        &self.row_offsets
    }

    /// Sender of each pair.
    pub fn senders(&self) -> &[u32] {
        &self.senders
    }

    /// Receiver of each pair.
    pub fn receivers(&self) -> &[u32] {
        &self.receivers
    }

    /// Neighbour count of each receiver.
    pub fn neighbor_counts(&self) -> Vec<usize> {
        self.row_offsets.windows(2).map(|w| w[1] - w[0]).collect()
    }

    /// The offsets `x_j - x_i` of all pairs, `[pairs, dim]`, as a differentiable function of
    /// the receivers' `[n_receivers, dim]` and the senders' `[n_senders, dim]` positions (the
    /// same tensor for a self graph); periodic images are a constant shift.
    pub fn offsets(&self, receivers: &Tensor, senders: &Tensor) -> Result<Tensor> {
        let check = |t: &Tensor, n: usize, what: &str| -> Result<()> {
            if t.dims() != [n, self.dim] {
                return Err(Error::Shape(format!(
                    "{what} positions have shape {:?}, the graph needs [{n}, {}]",
                    t.dims(),
                    self.dim
                )));
            }
            Ok(())
        };
        check(receivers, self.n_receivers, "receiver")?;
        check(senders, self.n_senders, "sender")?;
        let device = receivers.device();
        let dtype = receivers.dtype();
        let idx = |v: &[u32]| Tensor::from_slice(v, v.len(), device);
        let d =
            (senders.index_select(&idx(&self.senders)?, 0)? - receivers.index_select(&idx(&self.receivers)?, 0)?)?;
        if !self.has_shifts {
            return Ok(d);
        }
        let shift = Tensor::from_slice(&self.shifts, (self.num_pairs(), self.dim), device)?.to_dtype(dtype)?;
        Ok((d + shift)?)
    }

    /// The offsets as plain numbers (no tensor), `[pairs * dim]`, for callers outside candle.
    pub fn offsets_f64<const D: usize>(&self, receivers: &[[f64; D]], senders: &[[f64; D]]) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.num_pairs() * D);
        for p in 0..self.num_pairs() {
            let (i, j) = (self.receivers[p] as usize, self.senders[p] as usize);
            for a in 0..D {
                out.push(senders[j][a] - receivers[i][a] + self.shifts[p * D + a]);
            }
        }
        out
    }

    /// Float dtype check helper for the op: positions and features must share it.
    pub(crate) fn check_float(t: &Tensor, what: &str) -> Result<()> {
        match t.dtype() {
            DType::F32 | DType::F64 => Ok(()),
            other => Err(Error::Shape(format!("{what} has dtype {other:?}; use f32 or f64"))),
        }
    }
}
