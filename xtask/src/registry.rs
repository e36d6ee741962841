//! The entry types and the crates whose entries xtask runs: one line per crate in [`all`].

pub use pbdl_core::registry::*;

/// Every crate's contribution, in tour order.
pub fn all() -> Vec<CrateTasks> {
    vec![
        crate::entries::core::tasks(),
        crate::entries::grid::tasks(),
        crate::entries::metrics::tasks(),
        crate::entries::optim::tasks(),
        crate::entries::particles::tasks(),
        crate::entries::diffusion::tasks(),
    ]
}

/// The crates selected by an optional name; an unknown name lists the known ones.
pub fn select(krate: Option<&str>) -> anyhow::Result<Vec<CrateTasks>> {
    let all = all();
    match krate {
        None => Ok(all),
        Some(name) => {
            let names: Vec<&str> = all.iter().map(|c| c.crate_name).collect();
            let known = names.join(", ");
            let picked: Vec<CrateTasks> = all.into_iter().filter(|c| c.crate_name == name).collect();
            anyhow::ensure!(!picked.is_empty(), "unknown crate `{name}`; known crates: {known}");
            Ok(picked)
        }
    }
}

/// With `only` set, checks that one of `crates` has an entry of that name (`names` lists a
/// crate's entries of the kind being run); otherwise lists the known names.
pub fn check_entry(
    crates: &[CrateTasks],
    only: Option<&str>,
    names: impl Fn(&CrateTasks) -> Vec<&'static str>,
) -> anyhow::Result<()> {
    let Some(name) = only else { return Ok(()) };
    let known: Vec<&str> = crates.iter().flat_map(&names).collect();
    anyhow::ensure!(known.contains(&name), "unknown entry `{name}`; entries here: {}", known.join(", "));
    Ok(())
}

/// Prints every registered entry.
pub fn print_list() {
    for c in all() {
        println!("{}", c.crate_name);
        for e in &c.tour {
            println!("  tour   {:<24} {}", e.name, e.about);
        }
        for e in &c.bench {
            println!("  bench  {:<24} {}", e.name, e.about);
        }
        for e in &c.stress {
            println!("  stress {:<24} {}", e.name, e.about);
        }
    }
}
