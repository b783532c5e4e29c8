use clap::Parser;

fn main() -> std::process::ExitCode {
    // A reader that closes the pipe early (`mireg export RUN --format tum | head`) ends the
    // process quietly, as it ends any Unix filter, instead of a panic in `println!` (Rust starts
    // programs with SIGPIPE ignored). Outputs are written to a temporary file and renamed when
    // complete, so no half-written output is left either way.
    #[cfg(unix)]
    // SAFETY: sets a signal's disposition to its default at start-up, before any thread runs.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    match mireg::cli::run(mireg::cli::Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) if e.downcast_ref::<mireg::cli::RegistrationFailed>().is_some() => {
            eprintln!("mireg: {e}");
            std::process::ExitCode::from(1)
        }
        Err(e) => {
            eprintln!("mireg: error: {}", mireg::cli::error_text(&e));
            std::process::ExitCode::from(2)
        }
    }
}
