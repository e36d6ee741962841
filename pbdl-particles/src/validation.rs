//! Published measurements to validate particle solvers against.
//!
//! * [`martin_moyce_1952`]: the dam-break surge front of Martin & Moyce (1952), water column of
//!   width `a` and height `2a`, as `(T, Z)` with `T = t sqrt(2 g / a)` and `Z = z / a`; the
//!   digitised points shipped with PySPH (`tests/data/dambreak_exp_data.csv`, embedded).
//!
//! ```
//! use pbdl_particles::validation::martin_moyce_1952;
//! let early: Vec<(f64, f64)> = martin_moyce_1952().into_iter().filter(|p| (1.0..=2.5).contains(&p.0)).collect();
//! assert_eq!(early.len(), 5);
//! assert_eq!(early[0], (1.212, 1.443));
//! ```

const DAM_BREAK_CSV: &str = include_str!("../tests/data/dambreak_exp_data.csv");

/// Martin & Moyce (1952) surge-front points `(T, Z)` of both column sizes, ascending in `T`.
pub fn martin_moyce_1952() -> Vec<(f64, f64)> {
    let mut points: Vec<(f64, f64)> = DAM_BREAK_CSV
        .lines()
        .filter(|l| l.starts_with("MM1952"))
        .filter_map(|l| {
            let mut f = l.split(',').skip(1).map(|s| s.trim().parse::<f64>());
            match (f.next(), f.next()) {
                (Some(Ok(t)), Some(Ok(z))) => Some((t, z)),
                _ => None,
            }
        })
        .collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    points
}
