//! `smlworld` subcommand (not implemented yet).

/// Arguments (not implemented yet).
#[derive(Debug, clap::Args)]
pub struct MockMocapArgs {}

/// Run the subcommand.
pub fn main(_args: MockMocapArgs) -> anyhow::Result<()> {
    anyhow::bail!("this subcommand is not implemented yet")
}
