//! The real data sets beside the checkout (`../shared/data`), which a fresh clone may lack.

use std::path::{Path, PathBuf};

/// `../shared/data/REL` when it exists; otherwise `None`, after saying on stderr that the test
/// is skipped.
pub fn shared_data(rel: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(rel);
    if p.exists() {
        Some(p)
    } else {
        eprintln!("skipping: {} not present", p.display());
        None
    }
}
