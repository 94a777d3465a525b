//! `smlworld` subcommand (not implemented yet).

/// Arguments (not implemented yet).
#[derive(Debug, clap::Args)]
pub struct RunArgs {}

/// Run the subcommand.
pub fn main(_args: RunArgs) -> anyhow::Result<()> {
    anyhow::bail!("this subcommand is not implemented yet")
}
