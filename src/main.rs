//! `anaglyph`: multispectral light fields from a camera array behind wide-band filters.
//! The binary parses the command line (`cli`), runs one command (`commands`) and prints
//! errors with their causes.

mod cli;
mod commands;
mod progress;

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    exit_quietly_when_output_closes();
    let args = cli::Args::parse();
    let filter = match args.verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(filter)),
        )
        .with_writer(std::io::stderr)
        .init();
    match commands::run(args.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", describe(&e));
            ExitCode::FAILURE
        }
    }
}

/// A closed standard output (`anaglyph rig show rig.toml | head`) ends the process as
/// it ends `cat` or `grep`, by SIGPIPE, instead of a panic on the next print: Rust
/// ignores SIGPIPE by default, this restores the system's default action.
fn exit_quietly_when_output_closes() {
    #[cfg(unix)]
    // SAFETY: called first in main, before any thread exists; SIG_DFL is a valid action.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// The error and its causes, joined by ": ", leaving out a cause whose text the message
/// already ends with (library errors such as a failed read print their source themselves).
fn describe(error: &anyhow::Error) -> String {
    let mut message = String::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if message.is_empty() {
            message = text;
        } else if !message.ends_with(&text) {
            message.push_str(": ");
            message.push_str(&text);
        }
    }
    message
}

#[cfg(test)]
mod tests {
    use super::describe;

    #[test]
    fn causes_already_in_the_message_are_not_repeated() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let error = anyhow::Error::new(anaglyph_core::Error::Io {
            path: "captures/r0c2.png".into(),
            source: io,
        })
        .context("reading the rig's captures");
        assert_eq!(
            describe(&error),
            "reading the rig's captures: captures/r0c2.png: no such file"
        );
    }
}
