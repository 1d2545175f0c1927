//! nia-train: training from config files, and `synth` (the synthetic dataset).
fn main() -> anyhow::Result<()> {
    Ok(())
}
