//! `gateway`: run, demo, sim, check, fleet, tags, scan.
//!
//! A thin main (linkerd2-proxy order): parse the command line, set up logging, load and validate
//! the config (exit 64 before any port is opened when it is wrong), create the Prometheus registry
//! of the process, then hand over to [`gateway::app`], which runs until SIGINT or SIGTERM and
//! drains within a grace period. The signal handlers are installed first of all: SIGHUP re-reads
//! the configuration file and the TLS files (`gateway run`), and never kills the process. `gateway run` saves configuration changes made over the REST API
//! to its `--config` file; `gateway demo` keeps them in memory.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use gateway::app::{MetricsRegistry, Overrides};
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
    Tags(TagsCommand),
    /// Find the slave addresses that answer on a serial bus, with their identity (FC 43/14,
    /// FC 17).
    Scan(gateway::scan::ScanArgs),
}

/// `gateway tags export | import`.
#[derive(Debug, Subcommand)]
enum TagsCommand {
    /// Print the tag list as CSV (header name,table,address,type,byte_order,bit,registers,scale,
    /// offset,decimals,unit,writable,description).
    Export {
        #[command(flatten)]
        owner: TagsOwnerArgs,
    },
    /// Replace the tag list in the config file with the tags of a CSV file (checked first as
    /// `gateway check` does; nothing is written on any problem; the file is replaced atomically,
    /// its comments kept, the previous version as FILE.prev).
    Import {
        #[command(flatten)]
        owner: TagsOwnerArgs,
        /// The CSV file (`-` for standard input).
        csv: PathBuf,
    },
}

/// Whose tag list: `--line L --device D`, or `--template NAME` (a `[templates.NAME]`).
#[derive(Debug, clap::Args)]
struct TagsOwnerArgs {
    /// The config file.
    #[arg(long, short)]
    config: PathBuf,
    /// The line of the device.
    #[arg(long, requires = "device", conflicts_with = "template")]
    line: Option<String>,
    /// The device.
    #[arg(long, requires = "line", conflicts_with = "template")]
    device: Option<String>,
    /// A template of the config's [templates] instead of a device.
    #[arg(long, required_unless_present = "line")]
    template: Option<String>,
}

// === impl TagsOwnerArgs ===

impl TagsOwnerArgs {
    fn owner(&self) -> gateway::app::tag_csv::TagOwner {
        use gateway::app::tag_csv::TagOwner;
        match (&self.line, &self.device, &self.template) {
            (Some(line), Some(device), _) => TagOwner::Device {
                line: line.clone(),
                device: device.clone(),
            },
            (_, _, template) => TagOwner::Template(template.clone().unwrap_or_default()),
        }
    }
}

/// Runs `gateway tags`: 0 done, 1 problems (printed on stderr), 2 no such file or owner.
fn tags_command(command: &TagsCommand) -> ExitCode {
    use gateway::app::tag_csv::{self, TagCsvError};
    let result = match command {
        TagsCommand::Export { owner } => {
            tag_csv::export(&owner.config, &owner.owner()).map(|csv| print!("{csv}"))
        }
        TagsCommand::Import { owner, csv } => tag_csv::open_csv(csv).and_then(|reader| {
            tag_csv::import_from(&owner.config, &owner.owner(), reader).map(|n| {
                println!(
                    "ok: {n} tags written to {} ({})",
                    owner.config.display(),
                    owner.owner().path()
                );
            })
        }),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e @ TagCsvError::Problems(_)) => {
            eprintln!(
                "{e}
nothing written"
            );
            ExitCode::from(1)
        }
        Err(e) => {
            eprintln!("gateway tags: {e}");
            ExitCode::from(2)
        }
    }
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
            gateway::app::init_logging("warn");
        }
        _ => gateway::app::init_logging("info"),
    }
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

/// The registry `/metrics` serves, with every family of the gateway registered: one per process.
fn metrics_registry() -> Result<MetricsRegistry, ExitCode> {
    MetricsRegistry::new().map_err(|e| {
        eprintln!("gateway: cannot register the metrics: {e}");
        ExitCode::from(EX_SOFTWARE)
    })
}

async fn async_main(command: Command) -> ExitCode {
    let shutdown = CancellationToken::new();
    // First thing: a SIGHUP from here on is remembered (and handled once the gateway runs)
    // instead of killing the process.
    let hangups = gateway::app::handle_signals(shutdown.clone());
    let result = match command {
        Command::Run {
            config,
            modbus_tcp,
            zenoh_listen,
            http,
            exit_on_duplicate_name,
        } => match gateway::app::load_config(&config).and_then(|cfg| {
            // What run would refuse later (the API token, a line that cannot start) is a
            // configuration error too: refused here, before any port opens.
            let issues = gateway::app::run_issues(&cfg);
            if issues.is_empty() {
                Ok(cfg)
            } else {
                Err(gateway::config::ConfigErrors { issues })
            }
        }) {
            Ok(cfg) => {
                let metrics = match metrics_registry() {
                    Ok(metrics) => metrics,
                    Err(code) => return code,
                };
                let overrides = Overrides {
                    modbus_tcp,
                    zenoh_listen,
                    telegram_every: None,
                    paced: false,
                    http,
                    config_file: Some(config.clone()),
                    metrics: Some(metrics),
                    acknowledge_mailboxes: false,
                    hangups: Some(hangups),
                    api_token_file: None,
                    exit_on_duplicate_name,
                };
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
            let metrics = match metrics_registry() {
                Ok(metrics) => metrics,
                Err(code) => return code,
            };
            let overrides = Overrides {
                modbus_tcp: Some(modbus_tcp),
                zenoh_listen: Some(zenoh_listen),
                telegram_every: Some(telegram_every),
                paced,
                http,
                config_file: None,
                metrics: Some(metrics),
                acknowledge_mailboxes: !no_mailbox_consumer,
                hangups: Some(hangups),
                api_token_file: token_file,
                exit_on_duplicate_name: false,
            };
            gateway::app::demo_named(name, overrides, shutdown).await
        }
        Command::Sim(args) => {
            // A simulator has nothing to re-read: a SIGHUP is logged as such and ignored.
            drop(hangups);
            gateway::sim::run(args, shutdown)
                .await
                .map_err(gateway::app::AppError::from)
        }
        Command::Fleet(command) => {
            drop(hangups);
            return ExitCode::from(gateway::zenoh_bridge::fleet_cli::run(command, shutdown).await);
        }
        Command::Tags(command) => return tags_command(&command),
        Command::Scan(args) => {
            drop(hangups);
            return match gateway::scan::run(args, shutdown).await {
                Ok(()) => ExitCode::SUCCESS,
                Err(e @ gateway::scan::ScanError::Usage(_)) => {
                    eprintln!("gateway scan: {e}");
                    ExitCode::from(EX_USAGE)
                }
                Err(e) => {
                    eprintln!("gateway scan: {e}");
                    ExitCode::FAILURE
                }
            };
        }
        Command::Check { config } => {
            return match gateway::app::check_command(&config) {
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
