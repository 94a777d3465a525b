//! `smlworld` subcommand (not implemented yet).

/// Arguments (not implemented yet).
#[derive(Debug, clap::Args)]
pub struct BenchArgs {}

/// Run the subcommand.
pub fn main(_args: BenchArgs) -> anyhow::Result<()> {
    anyhow::bail!("this subcommand is not implemented yet")
}
