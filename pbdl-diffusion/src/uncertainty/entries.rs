//! This part's `cargo xtask` entries (tour, bench, stress).

use pbdl_core::bench::BenchRow;
use pbdl_core::registry::{Entry, StressCheck, TourOutcome};

/// Tour, bench and stress entries of this part.
pub(crate) type Entries = (Vec<Entry<TourOutcome>>, Vec<Entry<Vec<BenchRow>>>, Vec<Entry<Vec<StressCheck>>>);

/// This part's entries (none yet: the acceptance run is the ignored test `uncertainty_wake`).
pub(crate) fn entries() -> Entries {
    (vec![], vec![], vec![])
}
