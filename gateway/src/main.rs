//! `gateway`: run, demo, sim, check, fleet, tags, scan.
//!
//! A thin main (linkerd2-proxy order): parse the command line, set up logging, install the signal
//! handlers first of all (SIGHUP re-reads the configuration file and the TLS files in `gateway
//! run`, and never kills the process), then hand the subcommand to its function and exit with its
//! code: [`gateway::app::run_file`] loads and validates the config (exit 64 before any port is
//! opened when it is wrong), creates the Prometheus registry of the process and runs until SIGINT
//! or SIGTERM, draining within a grace period; `gateway run` saves configuration changes made
//! over the REST API to its `--config` file, `gateway demo` ([`gateway::app::demo_command`])
//! keeps them in memory.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use gateway::app::{self, tag_csv, AppError, Overrides};
use tokio_util::sync::CancellationToken;

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
        /// The zenoh session listens on this endpoint only, multicast scouting off.
        #[arg(long, value_name = "ENDPOINT")]
        zenoh_listen: Option<String>,
        /// Serve HTTP (REST API, /healthz, /readyz, /metrics) here instead of `[http] listen`.
        #[arg(long, value_name = "ADDR")]
        http: Option<SocketAddr>,
        /// Refuse the start (exit 64) when another zenoh session holds this gateway's name,
        /// instead of serving the lines, Modbus TCP and REST without zenoh until it is free.
        #[arg(long)]
        exit_on_duplicate_name: bool,
    },
    /// Run the embedded demo: virtual serial lines with simulated devices.
    Demo {
        /// Listen for Modbus TCP here.
        #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:5020")]
        modbus_tcp: SocketAddr,
        /// The zenoh peer listens on this endpoint (multicast scouting off).
        #[arg(long, value_name = "ENDPOINT", default_value = "tcp/127.0.0.1:7447")]
        zenoh_listen: String,
        /// How often the simulated 3964R and ASCII partners send a telegram of their own
        /// (0 = never).
        #[arg(long, value_name = "DURATION", default_value = "1s", value_parser = humantime::parse_duration)]
        telegram_every: std::time::Duration,
        /// Put every line on a paced link: each byte is delivered after its character time at the
        /// line's baud rate and frame, as on a cable.
        #[arg(long)]
        paced: bool,
        /// Do not acknowledge the mailboxes' oldest telegrams when they are half full (the demo
        /// does by default, so that they never overflow): for trying out overflows.
        #[arg(long)]
        no_mailbox_consumer: bool,
        /// Serve HTTP (REST API, /healthz, /readyz, /metrics) here instead of the demo
        /// config's 127.0.0.1:8080.
        #[arg(long, value_name = "ADDR")]
        http: Option<SocketAddr>,
        /// The gateway's name (zenoh prefix gw/<name>) instead of `demo`, so that several demos
        /// can share one zenoh fabric.
        #[arg(long, value_name = "NAME")]
        name: Option<String>,
        /// REST changes need the bearer token in this file (named `default`, role admin)
        /// instead of being accepted without one.
        #[arg(long, value_name = "FILE")]
        token_file: Option<PathBuf>,
    },
    /// Run simulated devices on a serial port (a pty end, or a real port): one, or a bus of
    /// several (`--device` repeated, each with its own `--address`).
    Sim(gateway::sim::SimArgs),
    /// Validate a config file: print every problem with its path, exit 1 if there is any.
    Check {
        /// The config file.
        #[arg(long, short)]
        config: PathBuf,
    },
    /// The gateways on the zenoh fabric: `status` (one table), `watch KEYEXPR` (samples).
    #[command(subcommand)]
    Fleet(gateway::zenoh_bridge::fleet_cli::FleetCommand),
    /// A device's (or a template's) tag list as CSV: export it, or import one into the file.
    #[command(subcommand)]
    Tags(tag_csv::TagsCommand),
    /// Find the slave addresses that answer on a serial bus, with their identity (FC 43/14,
    /// FC 17).
    Scan(gateway::scan::ScanArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if matches!(
        cli.command,
        Command::Check { .. } | Command::Tags(_) | Command::Fleet(_) | Command::Scan(_)
    ) {
        gateway::sigpipe::end_on_closed_stdout();
    }
    match cli.command {
        Command::Scan(_) => gateway::scan::init_logging(),
        Command::Check { .. } | Command::Tags(_) | Command::Fleet(_) => {
            app::init_logging("warn");
        }
        _ => app::init_logging("info"),
    }
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("gateway: cannot start the runtime: {e}");
            return ExitCode::from(app::EX_SOFTWARE);
        }
    };
    let code = runtime.block_on(gateway::task::watch("main", async_main(cli.command)));
    // Empty unless built with `stall-watch`.
    eprint!("{}", gateway::task::stalls());
    code
}

async fn async_main(command: Command) -> ExitCode {
    let shutdown = CancellationToken::new();
    // First thing: a SIGHUP from here on is remembered (and handled once the gateway runs)
    // instead of killing the process.
    let hangups = app::handle_signals(shutdown.clone());
    let code = match command {
        Command::Run {
            config,
            modbus_tcp,
            zenoh_listen,
            http,
            exit_on_duplicate_name,
        } => {
            let overrides = Overrides {
                modbus_tcp,
                zenoh_listen,
                http,
                hangups: Some(hangups),
                exit_on_duplicate_name,
                ..Overrides::default()
            };
            app::run_file(&config, overrides, shutdown).await
        }
        Command::Demo {
            modbus_tcp,
            zenoh_listen,
            http,
            telegram_every,
            paced,
            no_mailbox_consumer,
            name,
            token_file,
        } => {
            let overrides = Overrides {
                modbus_tcp: Some(modbus_tcp),
                zenoh_listen: Some(zenoh_listen),
                telegram_every: Some(telegram_every),
                paced,
                http,
                acknowledge_mailboxes: !no_mailbox_consumer,
                hangups: Some(hangups),
                api_token_file: token_file,
                ..Overrides::default()
            };
            app::demo_command(name, overrides, shutdown).await
        }
        Command::Sim(args) => {
            // A simulator has nothing to re-read: a SIGHUP is logged as such and ignored.
            drop(hangups);
            app::exit_code(
                gateway::sim::run(args, shutdown)
                    .await
                    .map_err(AppError::from),
            )
        }
        Command::Fleet(command) => {
            drop(hangups);
            gateway::zenoh_bridge::fleet_cli::run(command, shutdown).await
        }
        Command::Tags(command) => tag_csv::command(&command),
        Command::Scan(args) => {
            drop(hangups);
            gateway::scan::command(args, shutdown).await
        }
        Command::Check { config } => u8::try_from(app::check_command(&config)).unwrap_or(1),
    };
    ExitCode::from(code)
}
