//! The `terrastream` command: parse, set up logging, run the command, exit with its status.
//! Each command lives in `cli/`; the work is in the library.

/// `println!` that does not panic when stdout is gone: a closed pipe (`terrastream inspect … |
/// head`) ends the process quietly, as it ends other Unix tools; any other write error is
/// reported.
macro_rules! outln {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = writeln!(std::io::stdout(), $($t)*) {
            if e.kind() != std::io::ErrorKind::BrokenPipe {
                eprintln!("error: cannot write to standard output: {e}");
                std::process::exit(1);
            }
            std::process::exit(0);
        }
    }};
}

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    cli::quiet_mesa_device_select();
    cli::raise_open_file_limit();
    let cli = cli::Cli::parse();
    let json_logs = cli::json_logs(&cli);
    let filter = tracing_subscriber::EnvFilter::try_new(&cli.log).unwrap_or_default();
    // Colour only on a terminal: a redirected log holds plain text.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    if json_logs {
        tracing_subscriber::fmt().json().with_env_filter(filter).with_writer(std::io::stderr).init();
    } else {
        tracing_subscriber::fmt().with_ansi(ansi).with_env_filter(filter).with_writer(std::io::stderr).init();
    }
    match cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", cli::error_chain(&e));
            if e.downcast_ref::<cli::plan::InputRefused>().is_some() {
                std::process::ExitCode::from(cli::plan::INPUT_REFUSED_EXIT)
            } else {
                std::process::ExitCode::FAILURE
            }
        }
    }
}
