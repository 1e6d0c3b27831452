//! `cosem`: collaborative semantic map matching, from the command line.

mod cli;

use clap::Parser;

/// Restores the default SIGPIPE action, so `cosem ... | head` ends quietly
/// like other command-line tools instead of failing on a closed stdout.
#[cfg(unix)]
fn default_sigpipe() {
    extern "C" {
        fn signal(signum: i32, handler: usize) -> usize;
    }
    const SIGPIPE: i32 = 13;
    const SIG_DFL: usize = 0;
    // SAFETY: `signal` is async-signal-safe and called before any thread starts.
    unsafe {
        signal(SIGPIPE, SIG_DFL);
    }
}

fn main() {
    #[cfg(unix)]
    default_sigpipe();
    cosem_host::knobs::spell_with(cli::args::flag);
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(code) => std::process::exit(i32::from(code)),
        Err(e) => {
            eprintln!("error: {e}");
            // Causes the message does not already say.
            let mut said = e.to_string();
            let mut source = e.source();
            while let Some(s) = source {
                let cause = s.to_string();
                if !said.contains(&cause) {
                    eprintln!("  caused by: {cause}");
                }
                said = cause;
                source = s.source();
            }
            std::process::exit(1);
        }
    }
}
