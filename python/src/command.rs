//! The `mireg` command inside the extension: the package's console script (`mireg._cli`) calls
//! [`cli_main`] with `sys.argv`, so `pip install ./python` ships the command line without a
//! second build of the crate.

use clap::Parser;
use pyo3::prelude::*;

use mireg::cli::{Cli, RegistrationFailed, error_text, run};

/// `cli_main(argv) -> int`: runs `mireg ARGV[1:]` as the `mireg` binary does (src/main.rs) and
/// returns its exit status: 0, 1 when a registration fails its checks, 2 on an error (clap's own
/// status for `--help`, `--version` and bad flags). Ctrl-C ends the process with 130 as the
/// binary does: the CLI installs its own signal handlers.
#[pyfunction]
pub fn cli_main(py: Python<'_>, argv: Vec<String>) -> i32 {
    let args = std::iter::once("mireg".to_string()).chain(argv.into_iter().skip(1));
    let cli = match Cli::try_parse_from(args) {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return e.exit_code();
        }
    };
    match py.detach(|| run(cli)) {
        Ok(()) => 0,
        Err(e) if e.downcast_ref::<RegistrationFailed>().is_some() => {
            eprintln!("mireg: {e}");
            1
        }
        Err(e) => {
            eprintln!("mireg: error: {}", error_text(&e));
            2
        }
    }
}
