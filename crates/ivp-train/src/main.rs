//! `ivp`: the command-line program. It parses the command line and hands each subcommand to
//! `ivp_train::cli`; everything else lives in the library.

use anyhow::{Context, Result};
use clap::Parser;
use ivp_train::cli::{bench, data, eval, infer, train, Cli, Command};

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// `mi_option_purge_delay` in mimalloc 3's option enum (libmimalloc-sys names no constant for it).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Keeps freed memory mapped instead of handing it back to the OS a moment later. A 1080p
/// inference allocates and frees about 2 GB of feature maps a pass, and on a VM the page faults
/// of mapping them again cost more than the convolutions (1080p inference 14.3 s -> 5.9 s, a
/// 256x256 training step 3.9 s -> 2.7 s); the resident size stays at the peak either way.
fn keep_freed_memory_mapped() {
    // SAFETY: called first thing in `main`, before any other thread exists (the option setter is
    // not thread-safe).
    unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) }
}

fn main() -> Result<()> {
    keep_freed_memory_mapped();
    let cli = Cli::parse();
    init_logging(cli.verbose);
    if let Some(n) = cli.threads {
        anyhow::ensure!(n > 0, "--threads must be at least 1");
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("setting up the thread pool")?;
    }
    let progress = !cli.quiet;
    match cli.command {
        Command::Warp(args) => data::run_warp(args, progress),
        Command::Eval(args) => eval::run_eval(args, progress),
        Command::Check(args) => data::run_check(args),
        Command::Generate(args) => data::run_generate(args, progress),
        Command::ShowSample(args) => data::run_show_sample(args),
        Command::Bench(args) => bench::run_bench(args),
        Command::Demo(args) => train::run_demo(args, progress),
        Command::Train(args) => train::run_train(args, progress),
        Command::Export(args) => train::run_export(args),
        Command::Infer(args) => infer::run_infer(args),
        Command::Upsample(args) => infer::run_upsample(args, progress),
    }
}

fn init_logging(verbose: u8) {
    let default = match verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).init();
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The enum index is hard-coded: this fails if a mimalloc upgrade moves `purge_delay`.
    #[test]
    fn the_purge_delay_option_is_the_one_set() {
        if std::env::var_os("MIMALLOC_PURGE_DELAY").is_some() {
            eprintln!("skipped: MIMALLOC_PURGE_DELAY is set in the environment");
            return;
        }
        // SAFETY: mi_option_get only reads; the test harness may run other tests at the same time,
        // none of which sets options.
        let default = unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) };
        assert_eq!(default, 1000, "mimalloc 3 purges freed memory after 1000 ms by default");
        keep_freed_memory_mapped();
        assert_eq!(unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) }, -1);
    }
}
