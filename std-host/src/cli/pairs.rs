//! `bino pairs`: the pairs of a data folder's PAIRS.tsv.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Result;
use bino_host::data::pairs::{read_index, Split};
use bino_host::io::checkout;
use clap::Args;

/// (developer) List the pairs of a data folder's PAIRS.tsv.
#[derive(Args)]
pub struct PairsArgs {
    /// Folder holding PAIRS.tsv; the default is the data folder beside the checkout.
    #[arg(long, default_value_os_t = checkout::path(checkout::DATA))]
    data: PathBuf,
    /// Only this split (train or eval).
    #[arg(long)]
    split: Option<Split>,
}

/// Runs the verb.
pub fn run(args: PairsArgs) -> Result<()> {
    let pairs = read_index(&args.data)?;
    let mut out = std::io::stdout().lock();
    for pair in pairs.iter().filter(|p| args.split.is_none_or(|s| p.split == s)) {
        let line = writeln!(
            out,
            "{}\t{}\t{}\t{}x{}\t{}",
            pair.pair_id,
            pair.split,
            pair.dataset,
            pair.width,
            pair.height,
            pair.left.display()
        );
        match line {
            // A closed pipe (`bino pairs | head`) just ends the listing.
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(()),
            other => other?,
        }
    }
    Ok(())
}
