use clap::Parser;

fn main() -> std::process::ExitCode {
    match mireg::cli::run(mireg::cli::Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("mireg: error: {}", mireg::cli::error_text(&e));
            std::process::ExitCode::from(2)
        }
    }
}
