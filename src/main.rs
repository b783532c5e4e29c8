use clap::Parser;

fn main() -> std::process::ExitCode {
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
