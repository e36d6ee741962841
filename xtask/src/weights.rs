//! `cargo xtask weights convert IN.pth OUT.safetensors`: the official LSiM / VolSiM checkpoints
//! (legacy PyTorch pickles) to the safetensors files that `pbdl_metrics` loads. The reading and
//! the layout live in [`pbdl_metrics::convert`]; this is the thin command-line side.

use anyhow::Context;
use std::path::Path;

/// Converts `input` and writes `output`, printing a one-line summary to stderr.
pub fn convert(input: &Path, output: &Path) -> anyhow::Result<()> {
    let c = pbdl_metrics::convert::convert_file(input)
        .with_context(|| format!("converting {} (an official LSiM.pth or MS_3scales.pth)", input.display()))?;
    c.write_safetensors(output).with_context(|| format!("writing {}", output.display()))?;
    let values: usize = c.tensors.iter().map(|(_, t)| t.shape.iter().product::<usize>()).sum();
    eprintln!(
        "{} -> {}: {} tensors, {values} values, metadata {:?}",
        input.display(),
        output.display(),
        c.tensors.len(),
        {
            let mut k: Vec<_> = c.metadata.keys().collect();
            k.sort();
            k
        }
    );
    Ok(())
}
