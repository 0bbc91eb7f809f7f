//! `humem token`: makes, lists and revokes the bearer tokens of the token
//! file (`auth.tokens_file`). A running server notices a change within a
//! second; no restart.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};
use humem_server::auth::tokens::{self, Role, TokenFile};

/// What `humem token` does.
#[derive(Debug, Subcommand)]
pub enum TokenCommand {
    /// Make a token for a robot and print it (the only time it is shown;
    /// only its hash is stored).
    Add {
        #[command(flatten)]
        file: TokenFileArg,
        /// The robot the token speaks for: requests must carry this
        /// robot_id (an admin may act for any robot).
        #[arg(long)]
        robot: String,
        /// What it may do; repeat for several.
        #[arg(long = "role", value_enum, default_values_t = [Role::Robot])]
        roles: Vec<Role>,
        /// Free text kept with it: who has it, what for.
        #[arg(long, default_value = "")]
        note: String,
    },
    /// Revoke a token by its id (the 8 hex digits after `hm1.`).
    Revoke {
        #[command(flatten)]
        file: TokenFileArg,
        /// The token's id.
        id: String,
    },
    /// List the tokens (ids, robots, roles, dates; never the tokens).
    List {
        #[command(flatten)]
        file: TokenFileArg,
    },
}

/// Which token file.
#[derive(Debug, Args)]
pub struct TokenFileArg {
    /// The token file (default: auth.tokens_file of the configuration).
    #[arg(long)]
    file: Option<PathBuf>,
}

impl TokenFileArg {
    fn resolve(&self, configured: Option<&Path>) -> anyhow::Result<PathBuf> {
        self.file
            .clone()
            .or_else(|| configured.map(Path::to_path_buf))
            .context("no token file: give --file or set auth.tokens_file (HUMEM_AUTH__TOKENS_FILE)")
    }
}

fn roles_text(roles: &[Role]) -> String {
    roles
        .iter()
        .map(|r| match r {
            Role::Robot => "robot",
            Role::Admin => "admin",
        })
        .collect::<Vec<_>>()
        .join(",")
}

fn created(unix: u64) -> String {
    humantime::format_rfc3339_seconds(std::time::UNIX_EPOCH + std::time::Duration::from_secs(unix))
        .to_string()
}

/// Runs a token command; `configured` is auth.tokens_file, if set.
pub fn run(command: TokenCommand, configured: Option<&Path>) -> anyhow::Result<()> {
    match command {
        TokenCommand::Add {
            file,
            robot,
            roles,
            note,
        } => {
            let path = file.resolve(configured)?;
            let (token, record) = tokens::add(&path, &robot, &roles, &note)?;
            eprintln!(
                "humem token: {} for robot {:?} ({}) in {}; this is the only time it is shown",
                record.id,
                record.robot,
                roles_text(&record.roles),
                path.display()
            );
            println!("{token}");
        }
        TokenCommand::Revoke { file, id } => {
            let path = file.resolve(configured)?;
            let record = tokens::revoke(&path, &id)?;
            eprintln!(
                "humem token: revoked {} (robot {:?}); servers refuse it within a second",
                record.id, record.robot
            );
        }
        TokenCommand::List { file } => {
            let path = file.resolve(configured)?;
            let file = TokenFile::read(&path)?;
            println!("| id | robot | roles | created | note |");
            println!("| --- | --- | --- | --- | --- |");
            for t in &file.tokens {
                println!(
                    "| {} | {} | {} | {} | {} |",
                    t.id,
                    t.robot,
                    roles_text(&t.roles),
                    created(t.created_unix),
                    t.note
                );
            }
        }
    }
    Ok(())
}
