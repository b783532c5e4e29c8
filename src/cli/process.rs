//! What every subcommand shares at the process boundary: the command line recorded in outputs
//! and the one-line error text `main` prints.

/// The command line as typed, recorded in outputs' metadata.
pub fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

/// The error and its causes on one line, `outer: inner: …`, each said once: a cause whose text
/// the line already ends with (an I/O error that its wrapper prints too) is left out.
pub fn error_text(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !text.ends_with(&c) {
            text.push_str(": ");
            text.push_str(&c);
        }
    }
    text
}
