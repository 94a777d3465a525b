//! `smlworld` subcommand (not implemented yet).

/// Arguments (not implemented yet).
#[derive(Debug, clap::Args)]
pub struct ViewArgs {}

/// Run the subcommand.
pub fn main(_args: ViewArgs) -> anyhow::Result<()> {
    anyhow::bail!("this subcommand is not implemented yet")
}
