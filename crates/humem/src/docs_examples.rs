//! The user docs' examples, checked against the real command line and
//! configuration loader, so that what a reader copies runs as written.
//!
//! Every fenced block of README.md, docs/, deploy/, docker/ and the client
//! READMEs is read:
//! - `sh` blocks: each command (continuation lines joined, heredocs and
//!   comments left out, pipelines and lists split) that runs `humem`
//!   (directly, through `cargo run`, `scripts/run.sh`, `docker exec` or
//!   `kubectl exec`) must parse with the real [`Cli`]; a `humem serve` must
//!   load its configuration (the file it names where the repository holds
//!   it, the `HUMEM_*` settings on its line or exported before it, its
//!   flags) with the real [`Config::load`] and pass the network rule the
//!   server applies at start; a script, tool or example a command runs must
//!   exist.
//! - `toml` blocks load with [`Config::load`] (unknown keys and bad values
//!   are refused as the server refuses them); `json` blocks parse;
//!   `python` blocks compile.
//!
//! A block that cannot be checked so says why on the line before its
//! fence: `<!-- docs-check: skip (REASON) -->`. The checker is a test of
//! the binary crate because it needs the binary's own parser; it lives
//! here rather than in `tests/` for that reason.

use std::path::{Path, PathBuf};

use clap::Parser;
use figment::providers::{Format as _, Serialized, Toml};
use figment::Figment;
use humem_server::config::Config;

use crate::cli::{Cli, Command};

/// The marker that exempts the next block, with its reason.
const SKIP: &str = "<!-- docs-check: skip";

/// One fenced block.
struct Block {
    /// 1-based line of the opening fence.
    line: usize,
    lang: String,
    /// Lines inside the fence, with their 1-based numbers.
    lines: Vec<(usize, String)>,
    skipped: bool,
}

/// The fenced blocks of a Markdown text.
fn blocks(text: &str) -> Vec<Block> {
    let mut out = Vec::new();
    let mut open: Option<Block> = None;
    let mut previous = "";
    for (i, raw) in text.lines().enumerate() {
        let fence = raw.trim_start().strip_prefix("```").map(str::trim);
        match (&mut open, fence) {
            (Some(_), Some("")) => out.push(open.take().expect("open")),
            (Some(block), _) => block.lines.push((i + 1, raw.to_string())),
            (None, Some(lang)) => {
                open = Some(Block {
                    line: i + 1,
                    lang: lang.to_string(),
                    lines: Vec::new(),
                    skipped: previous.trim_start().starts_with(SKIP),
                })
            }
            (None, None) => {}
        }
        if !raw.trim().is_empty() {
            previous = raw;
        }
    }
    out
}

/// The commands of a shell block: (line, command), continuation lines and
/// quoted strings that span lines joined, comments and heredoc bodies
/// left out.
fn commands(block: &Block) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut pending: Option<(usize, String)> = None;
    let mut heredoc: Option<String> = None;
    for (line, raw) in &block.lines {
        if let Some(end) = &heredoc {
            if raw.trim() == end {
                heredoc = None;
            }
            continue;
        }
        let text = raw.trim();
        let text = text.strip_prefix("$ ").unwrap_or(text);
        if pending.is_none() && (text.is_empty() || text.starts_with('#')) {
            continue;
        }
        if let Some(at) = text.find("<<") {
            let tag = text[at + 2..]
                .trim_start_matches('-')
                .split_whitespace()
                .next()
                .unwrap_or("")
                .trim_matches(|c| c == '\'' || c == '"');
            if !tag.is_empty() {
                heredoc = Some(tag.to_string());
            }
        }
        let (start, mut joined) = pending.take().unwrap_or((*line, String::new()));
        if let Some(head) = text.strip_suffix('\\') {
            joined.push_str(head);
            joined.push(' ');
            pending = Some((start, joined));
        } else {
            joined.push_str(text);
            if shell_words::split(&joined).is_err() {
                // A quoted string goes on on the next line.
                joined.push(' ');
                pending = Some((start, joined));
            } else {
                out.push((start, joined));
            }
        }
    }
    out.extend(pending);
    out
}

/// `command` with the variables of `env` (`$name`, `${name}`) replaced by
/// their values; others are left as they are.
fn expand(command: &str, env: &[(String, String)]) -> String {
    let mut out = command.to_string();
    for (name, value) in env.iter().rev() {
        out = out.replace(&format!("${{{name}}}"), value);
        let plain = format!("${name}");
        let mut expanded = String::new();
        let mut rest = out.as_str();
        while let Some(at) = rest.find(&plain) {
            let after = &rest[at + plain.len()..];
            let whole = !after.starts_with(|c: char| c.is_ascii_alphanumeric() || c == '_');
            expanded.push_str(&rest[..at]);
            expanded.push_str(if whole { value } else { &plain });
            rest = after;
        }
        expanded.push_str(rest);
        out = expanded;
    }
    out
}

/// The tokens of a command split into the simple commands of its
/// pipelines and lists, without redirections.
fn simple_commands(tokens: Vec<String>) -> Vec<Vec<String>> {
    let mut out = vec![Vec::new()];
    let mut tokens = tokens.into_iter();
    while let Some(token) = tokens.next() {
        match token.as_str() {
            "|" | "||" | "&&" | ";" | "&" => out.push(Vec::new()),
            ">" | ">>" | "<" | "2>" | "2>>" | "&>" => {
                tokens.next();
            }
            t if t.starts_with('>') || t.starts_with("2>") || t.starts_with("&>") => {}
            t if t.ends_with(';') && t.len() > 1 => {
                out.last_mut()
                    .expect("one")
                    .push(t.trim_end_matches(';').into());
                out.push(Vec::new());
            }
            _ => out.last_mut().expect("one").push(token),
        }
    }
    out.retain(|c| !c.is_empty());
    out
}

/// `NAME=value` with a shell variable's name.
fn assignment(token: &str) -> Option<(&str, &str)> {
    let (name, value) = token.split_once('=')?;
    let valid = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_');
    valid.then_some((name, value))
}

/// `HUMEM_*` settings as a configuration layer, the way the server reads
/// its environment (`HUMEM_A__B=v` is `a.b = v`, a value that is not TOML
/// being a string).
fn settings_layer(env: &[(String, String)]) -> Figment {
    let mut figment = Figment::new();
    for (name, value) in env {
        let Some(key) = name
            .strip_prefix("HUMEM_")
            .filter(|k| humem_server::config::is_setting(k))
        else {
            continue;
        };
        let key = key.to_ascii_lowercase().replace("__", ".");
        let value: figment::value::Value = value.parse().expect("any string is a value");
        figment = figment.merge(Serialized::default(&key, value));
    }
    figment
}

/// Where `humem`'s arguments start in a simple command, if it runs humem.
fn humem_arguments(tokens: &[String]) -> Option<Vec<String>> {
    let program = tokens.first()?;
    let is_humem = |t: &str| Path::new(t).file_name().is_some_and(|n| n == "humem");
    match program.as_str() {
        p if is_humem(p) => Some(tokens[1..].to_vec()),
        "cargo" if tokens.iter().any(|t| t == "run") => {
            let at = tokens.iter().position(|t| t == "--")?;
            Some(tokens[at + 1..].to_vec())
        }
        p if p.ends_with("scripts/run.sh") => {
            let mut args = vec!["serve".to_string()];
            args.extend(tokens[1..].iter().cloned());
            Some(args)
        }
        "docker" | "kubectl" => {
            // `docker exec NAME humem SUB …`, `kubectl exec … -- humem SUB …`.
            let subcommands: Vec<String> = <Cli as clap::CommandFactory>::command()
                .get_subcommands()
                .map(|c| c.get_name().to_string())
                .collect();
            let at = (1..tokens.len()).rev().find(|&i| {
                is_humem(&tokens[i]) && tokens.get(i + 1).is_some_and(|s| subcommands.contains(s))
            })?;
            Some(tokens[at + 1..].to_vec())
        }
        _ => None,
    }
}

/// A repository path a command runs (a script, a tool, an example), if the
/// command's program or a Python script argument is one.
fn repository_path(tokens: &[String]) -> Option<&String> {
    const TOP: [&str; 7] = [
        "scripts/",
        "tools/",
        "clients/",
        "client-cpp/",
        "deploy/",
        "docker/",
        "proto/",
    ];
    let program = tokens.first()?;
    let local = |t: &String| {
        TOP.iter()
            .any(|top| t.trim_start_matches("./").starts_with(top))
    };
    if local(program) {
        return Some(program);
    }
    let python = Path::new(program)
        .file_name()
        .is_some_and(|n| n.to_string_lossy().starts_with("python"));
    if python {
        return tokens[1..]
            .iter()
            .find(|t| !t.starts_with('-'))
            .filter(|t| local(t));
    }
    None
}

/// Checks one command; `env` holds the variables exported before it in
/// its block.
fn check_command(
    root: &Path,
    command: &str,
    env: &mut Vec<(String, String)>,
) -> Result<(), String> {
    let command = expand(command, env);
    let tokens = shell_words::split(&command).map_err(|e| format!("not a shell command ({e})"))?;
    for mut tokens in simple_commands(tokens) {
        // `for NAME in FIRST …`: the loop's body is checked with the first value.
        if tokens.len() > 3 && tokens[0] == "for" && tokens[2] == "in" {
            env.push((tokens[1].clone(), tokens[3].clone()));
            continue;
        }
        while matches!(tokens[0].as_str(), "export" | "do" | "then" | "else") {
            tokens.remove(0);
            if tokens.is_empty() {
                break;
            }
        }
        if tokens.is_empty() || matches!(tokens[0].as_str(), "done" | "fi") {
            continue;
        }
        let mut local = env.clone();
        let mut at = 0;
        while let Some((name, value)) = tokens.get(at).and_then(|t| assignment(t)) {
            local.push((name.to_string(), value.to_string()));
            at += 1;
        }
        if at == tokens.len() {
            *env = local;
            continue;
        }
        let tokens = &tokens[at..];
        if let Some(path) = repository_path(tokens) {
            if !root.join(path.trim_start_matches("./")).exists() {
                return Err(format!("{path} is not in the repository"));
            }
        }
        if let Some(args) = humem_arguments(tokens) {
            check_humem(root, &args, &local)?;
        }
    }
    Ok(())
}

/// Parses `humem ARGS` with the real CLI; a `serve` also loads its
/// configuration and passes the start's network rule.
fn check_humem(root: &Path, args: &[String], env: &[(String, String)]) -> Result<(), String> {
    let argv = std::iter::once("humem".to_string()).chain(args.iter().cloned());
    let cli = Cli::try_parse_from(argv).map_err(|e| {
        let rendered = e.render().to_string();
        format!(
            "humem {}: {}",
            args.join(" "),
            rendered.lines().next().unwrap_or_default()
        )
    })?;
    let Command::Serve(serve) = &cli.command else {
        return Ok(());
    };
    let file = cli.config.clone().or_else(|| {
        env.iter()
            .find(|(n, _)| n == "HUMEM_CONFIG")
            .map(|(_, v)| PathBuf::from(v))
    });
    let file = match file {
        // A file outside the repository (a user's, or an image's) is not
        // here to load.
        Some(f) if !root.join(&f).exists() => return Ok(()),
        Some(f) => Some(root.join(f)),
        None => None,
    };
    let overrides = settings_layer(env).merge(serve.overrides());
    let config = Config::load(file.as_deref(), overrides)
        .map_err(|e| format!("humem {}: {e}", args.join(" ")))?;
    let credentials = humem_server::auth::requires_credentials(&config.auth, &config.server.tls);
    humem_server::server::check_exposure(&config, credentials).map_err(|e| {
        format!(
            "humem {}: the server would refuse to start: {e}",
            args.join(" ")
        )
    })
}

/// Checks one block; gives its problems as (line, message).
fn check_block(root: &Path, block: &Block) -> Vec<(usize, String)> {
    if block.skipped {
        return Vec::new();
    }
    let mut problems = Vec::new();
    match block.lang.as_str() {
        "sh" | "bash" | "shell" | "console" => {
            let mut env = Vec::new();
            for (line, command) in commands(block) {
                if let Err(e) = check_command(root, &command, &mut env) {
                    problems.push((line, e));
                }
            }
        }
        "toml" => {
            let text: String = block.lines.iter().map(|(_, l)| format!("{l}\n")).collect();
            let overrides = Figment::from(Toml::string(&text));
            if let Err(e) = Config::load(None, overrides) {
                problems.push((block.line, format!("this configuration is refused: {e}")));
            }
        }
        "json" => {
            let text: String = block.lines.iter().map(|(_, l)| format!("{l}\n")).collect();
            if let Err(e) = serde_json::from_str::<serde_json::Value>(&text) {
                problems.push((block.line, format!("not JSON: {e}")));
            }
        }
        "python" => {
            let text: String = block.lines.iter().map(|(_, l)| format!("{l}\n")).collect();
            if let Err(e) = python_compiles(&text) {
                problems.push((block.line, e));
            }
        }
        _ => {}
    }
    problems
}

/// Whether `python3` compiles `source` (skipped where there is none).
fn python_compiles(source: &str) -> Result<(), String> {
    use std::io::Write;
    let child = std::process::Command::new("python3")
        .args(["-c", "import ast, sys; ast.parse(sys.stdin.read())"])
        .stdin(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn();
    let Ok(mut child) = child else {
        return Ok(());
    };
    child
        .stdin
        .take()
        .expect("piped")
        .write_all(source.as_bytes())
        .map_err(|e| e.to_string())?;
    let output = child.wait_with_output().map_err(|e| e.to_string())?;
    if output.status.success() {
        Ok(())
    } else {
        let stderr = String::from_utf8_lossy(&output.stderr);
        Err(format!(
            "Python that does not compile: {}",
            stderr.lines().last().unwrap_or_default()
        ))
    }
}

/// Every problem of one Markdown text, as `file:line: message`.
fn check_text(root: &Path, name: &str, text: &str) -> Vec<String> {
    blocks(text)
        .iter()
        .flat_map(|b| check_block(root, b))
        .map(|(line, e)| format!("{name}:{line}: {e}"))
        .collect()
}

/// The Markdown files users read.
fn user_docs(root: &Path) -> Vec<PathBuf> {
    fn markdown_under(dir: &Path, out: &mut Vec<PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            if path.is_dir() {
                markdown_under(&path, out);
            } else if path.extension().is_some_and(|e| e == "md") {
                out.push(path);
            }
        }
    }
    let mut files = vec![root.join("README.md")];
    for dir in ["docs", "deploy", "docker", "clients/python", "client-cpp"] {
        let mut found = Vec::new();
        markdown_under(&root.join(dir), &mut found);
        files.extend(found.into_iter().filter(|f| {
            !f.components()
                .any(|c| c.as_os_str() == "node_modules" || c.as_os_str() == ".venv")
        }));
    }
    files.sort();
    files
}

#[cfg(test)]
mod tests {
    use super::*;

    fn root() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
    }

    #[test]
    fn every_example_in_the_docs_parses_loads_and_names_real_files() {
        let root = root();
        let mut problems = Vec::new();
        let mut checked = 0;
        for file in user_docs(&root) {
            let text = std::fs::read_to_string(&file).unwrap();
            let name = file.strip_prefix(&root).unwrap().display().to_string();
            checked += blocks(&text).iter().filter(|b| !b.skipped).count();
            problems.extend(check_text(&root, &name, &text));
        }
        assert!(checked > 40, "only {checked} blocks found");
        assert!(
            problems.is_empty(),
            "{} documented examples are broken:\n{}",
            problems.len(),
            problems.join("\n")
        );
    }

    #[test]
    fn a_broken_example_is_caught_and_a_marked_one_is_left() {
        let root = root();
        let doc = r#"
```sh
humem serve --listen 127.0.0.1:50051
humem stats --server http://127.0.0.1:50051 | head
HUMEM_METRICS__LISTEN=127.0.0.1:9465 humem serve \
    --data-dir ./data-b
humem statz
humem query --no-such-flag
scripts/run.sh --listen 0.0.0.0:50051
HUMEM_VPR__NO_SUCH=1 humem serve
export HUMEM_SERVER__LISTEN=0.0.0.0:50051
humem serve
python3 clients/python/examples/no_such.py
scripts/no-such.sh
cat <<EOF
humem not-checked-inside-a-heredoc
EOF
```

```toml
[vpr]
no_such_setting = 3
```

<!-- docs-check: skip (a user's own data) -->
```sh
humem statz
```

```json
{"a": 1,}
```
"#;
        let problems = check_text(&root, "doc.md", doc);
        let expected = [
            "doc.md:7: humem statz: error: unrecognized subcommand 'statz'",
            "doc.md:8: humem query --no-such-flag: error: unexpected argument '--no-such-flag'",
            "doc.md:9: humem serve --listen 0.0.0.0:50051: the server would refuse to start: refusing to serve 0.0.0.0:50051",
            "doc.md:10: humem serve: configuration:",
            "doc.md:12: humem serve: the server would refuse to start",
            "doc.md:13: clients/python/examples/no_such.py is not in the repository",
            "doc.md:14: scripts/no-such.sh is not in the repository",
            "doc.md:20: this configuration is refused: configuration:",
            "doc.md:30: not JSON",
        ];
        assert_eq!(problems.len(), expected.len(), "{problems:#?}");
        for (problem, expected) in problems.iter().zip(expected) {
            assert!(
                problem.starts_with(expected),
                "{problem}\nexpected {expected}"
            );
        }
        assert!(problems[3].contains("no_such"), "{}", problems[3]);
        assert!(problems[7].contains("no_such_setting"), "{}", problems[7]);
    }
}
