//! `smlworld` subcommand (not implemented yet).

/// Arguments (not implemented yet).
#[derive(Debug, clap::Args)]
pub struct RenderArgs {}

/// Run the subcommand.
pub fn main(_args: RenderArgs) -> anyhow::Result<()> {
    anyhow::bail!("this subcommand is not implemented yet")
}
