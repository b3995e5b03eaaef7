//! `gateway`: run, demo, sim, check.
//!
//! A thin main (linkerd2-proxy order): parse the command line, set up logging, load and validate
//! the config (exit 64 before any port is opened when it is wrong), then hand over to
//! [`gateway::app`], which runs until SIGINT or SIGTERM and drains within a grace period.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use tokio_util::sync::CancellationToken;

/// sysexits.h EX_USAGE: the configuration is unusable.
const EX_USAGE: u8 = 64;
/// sysexits.h EX_SOFTWARE: the gateway stopped on an internal error.
const EX_SOFTWARE: u8 = 70;

#[derive(Debug, Parser)]
#[command(
    name = "gateway",
    version,
    about = "CP 341 style serial gateway: serial lines to Modbus TCP"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run with a config file (TOML).
    Run {
        /// The config file.
        #[arg(long, short)]
        config: PathBuf,
        /// Listen for Modbus TCP here instead of the config's `modbus_tcp.listen`.
        #[arg(long, value_name = "ADDR")]
        modbus_tcp: Option<SocketAddr>,
    },
    /// Run the embedded demo: virtual serial lines with simulated devices.
    Demo {
        /// Listen for Modbus TCP here.
        #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:5020")]
        modbus_tcp: SocketAddr,
    },
    /// Run one simulated device on a serial port (a pty end, or a real port).
    Sim(gateway::sim::SimArgs),
    /// Validate a config file: print every problem with its path, exit 1 if there is any.
    Check {
        /// The config file.
        #[arg(long, short)]
        config: PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    gateway::app::init_logging();
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("gateway: cannot start the runtime: {e}");
            return ExitCode::from(EX_SOFTWARE);
        }
    };
    runtime.block_on(async_main(cli.command))
}

async fn async_main(command: Command) -> ExitCode {
    let shutdown = CancellationToken::new();
    tokio::spawn(gateway::app::cancel_on_signal(shutdown.clone()));
    let result = match command {
        Command::Run { config, modbus_tcp } => match gateway::config::load(&config) {
            Ok(cfg) => {
                let overrides = gateway::app::Overrides { modbus_tcp };
                gateway::app::run(cfg, overrides, shutdown).await
            }
            Err(errors) => {
                eprintln!(
                    "gateway: {} is not a valid config:\n{errors}",
                    config.display()
                );
                return ExitCode::from(EX_USAGE);
            }
        },
        Command::Demo { modbus_tcp } => {
            let overrides = gateway::app::Overrides {
                modbus_tcp: Some(modbus_tcp),
            };
            gateway::app::demo(overrides, shutdown).await
        }
        Command::Sim(args) => gateway::sim::run(args, shutdown)
            .await
            .map_err(gateway::app::AppError::from),
        Command::Check { config } => {
            return match gateway::config::check_command(&config) {
                0 => ExitCode::SUCCESS,
                code => ExitCode::from(u8::try_from(code).unwrap_or(1)),
            };
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!(error = %e, "gateway stopped");
            eprintln!("gateway: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}
