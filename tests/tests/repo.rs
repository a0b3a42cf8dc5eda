//! What the repository promises about itself: CI runs the README's test
//! command and nothing may be skipped there, the README's images come from a
//! script, its farm commands can be found, and its layout names what exists.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(root().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// CI runs the README's test command and no other cargo command but the
/// denoiser's tests the README names, so that the command a reader copies
/// works on a fresh clone: no extra `cargo build` may hide that the tests
/// build the binaries they start.
#[test]
fn ci_runs_exactly_the_readme_s_test_command() {
    let readme = read("README.md");
    assert!(
        readme.contains("\ncargo test --workspace "),
        "the README's test command"
    );
    let ci = read(".ci/run");
    let cargo: Vec<&str> = ci
        .lines()
        .map(str::trim)
        .filter(|l| !l.starts_with('#') && !l.starts_with("echo"))
        .filter(|l| l.contains("cargo "))
        .collect();
    // Once as a newcomer runs it, once more beside two CPU hogs (the suite
    // must pass on a busy machine): the same command both times. Between
    // them, the denoiser's tests with the library CI fetches, as the
    // README's Tests section gives them.
    // Last, trevi-submit --denoise against a build with the library, as
    // the README gives it.
    const DENOISE: &str = "cargo test -p trevi-denoise --features oidn";
    const DENOISE_CLI: &str =
        "cargo test --workspace --features trevi-submit/denoise --test denoise_cli";
    assert!(
        readme.contains(DENOISE_CLI),
        "the README gives the denoise_cli command"
    );
    assert!(
        readme.contains(DENOISE),
        "the README gives the denoiser's test command"
    );
    let denoise = format!("OIDN_DIR=\"$oidn_dir\" {DENOISE}");
    assert_eq!(
        cargo,
        [
            "cargo test --workspace",
            denoise.as_str(),
            "cargo test --workspace",
            DENOISE_CLI,
        ],
        ".ci/run's cargo commands"
    );
    assert!(ci.contains(&format!("export {}=1", common::REQUIRE_ALL)));
}

/// A test that lacks a tool printed "SKIPPED" and passed, in CI too. With
/// TREVI_REQUIRE_ALL=1 it fails. This test runs itself as a child that
/// checks for a command that does not exist, with and without the switch.
#[test]
fn a_missing_tool_fails_the_test_under_trevi_require_all() {
    const CHILD: &str = "TREVI_TEST_SKIP_CHILD";
    if std::env::var_os(CHILD).is_some() {
        let have = common::have_command("trevi-no-such-command", "--version", "this check");
        assert!(!have);
        return;
    }
    let run = |all: &str| {
        Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "a_missing_tool_fails_the_test_under_trevi_require_all",
                "--nocapture",
            ])
            .env(CHILD, "1")
            .env(common::REQUIRE_ALL, all)
            .output()
            .unwrap()
    };
    let skipped = run("0");
    let text = String::from_utf8_lossy(&skipped.stderr);
    assert!(skipped.status.success(), "{text}");
    assert!(
        text.contains("SKIPPED: the trevi-no-such-command command is missing"),
        "{text}"
    );
    let failed = run("1");
    let text = String::from_utf8_lossy(&failed.stderr);
    assert!(!failed.status.success(), "{text}");
    assert!(text.contains("nothing may be skipped"), "{text}");
}

/// Two measurements were `#[ignore]`d without saying why or how to run
/// them: every ignored test in the workspace gives its reason.
#[test]
fn no_test_is_ignored_without_a_reason() {
    let mut bare = Vec::new();
    let mut dirs = vec![root()];
    while let Some(dir) = dirs.pop() {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = e.path();
            let name = e.file_name().to_string_lossy().into_owned();
            if p.is_dir() {
                if !name.starts_with('.') && name != "target" {
                    dirs.push(p);
                }
            } else if name.ends_with(".rs") {
                let text = std::fs::read_to_string(&p).unwrap_or_default();
                for (i, line) in text.lines().enumerate() {
                    if line.trim() == "#[ignore]" {
                        bare.push(format!("{}:{}", p.display(), i + 1));
                    }
                }
            }
        }
    }
    assert!(
        bare.is_empty(),
        "say why and how to run them (#[ignore = \"…\"]): {bare:?}"
    );
}

/// The README shows what the code renders today: `docs/images/make.sh`
/// renders its images from the examples; every README image but the
/// monitor's screenshot is one of the script's, and every one of the
/// script's is shown.
#[test]
fn the_readme_s_images_are_the_ones_docs_images_make_sh_renders() {
    let script = read("docs/images/make.sh");
    let list = script
        .split_once("images=(")
        .and_then(|(_, rest)| rest.split_once("\n)"))
        .expect("make.sh's images=( … ) list")
        .0;
    let mut made: Vec<String> = Vec::new();
    for line in list.lines().map(|l| l.trim().trim_matches('"')) {
        if line.is_empty() {
            continue;
        }
        let parts: Vec<&str> = line.split_whitespace().collect();
        let [scene, camera, image] = parts[..] else {
            panic!("make.sh: {line:?} is not `scene camera image`");
        };
        let xml = read(scene);
        assert!(
            xml.contains(&format!("<camera id=\"{camera}\"")),
            "{scene} has no camera {camera}"
        );
        assert!(root().join("docs/images").join(image).is_file(), "{image}");
        made.push(image.to_string());
    }
    made.sort();

    let readme = read("README.md");
    let mut shown: Vec<String> = readme
        .split("](docs/images/")
        .skip(1)
        .map(|rest| rest.split(')').next().unwrap().to_string())
        .filter(|image| image != "monitor.png")
        .collect();
    shown.sort();
    shown.dedup();
    assert_eq!(made, shown, "make.sh's images and the README's");
}

/// The README's farm section ran `trevi-coordinator` and `trevi-worker` as
/// if installed, without saying how to install them.
#[test]
fn the_readme_installs_the_farm_s_programs_before_running_them() {
    let readme = read("README.md");
    let farm = readme
        .split_once("## A render farm")
        .expect("the README's farm section")
        .1;
    let first_run = farm
        .find("trevi-coordinator --")
        .expect("the coordinator's command line");
    for package in ["coordinator", "worker", "submit"] {
        // --locked: the versions of Cargo.lock, as the tests built them.
        let install = format!("cargo install --locked --path {package}");
        let at = farm
            .find(&install)
            .unwrap_or_else(|| panic!("the farm section lacks `{install}`"));
        assert!(at < first_run, "`{install}` comes after the first command");
        assert!(root().join(package).join("Cargo.toml").is_file());
    }
}

/// The README's layout section is the map a newcomer reads first: every
/// directory and `src/` path it names exists, and every module of the
/// tracer (core/src) is on it.
#[test]
fn the_readme_s_layout_names_what_exists() {
    let readme = read("README.md");
    let section = readme
        .split("## How it is built\n\n```\n")
        .nth(1)
        .and_then(|s| s.split("```").next())
        .expect("the README's layout block under \"## How it is built\"");
    let mut krate = String::new();
    let mut core_named = Vec::new();
    let mut missing = Vec::new();
    for line in section.lines() {
        if !line.starts_with(' ') {
            if let Some(dir) = line.split_whitespace().next() {
                krate = dir.to_string();
                if !root().join(dir).is_dir() {
                    missing.push(dir.to_string());
                }
            }
            continue;
        }
        for word in line.split(|c: char| c.is_whitespace() || c == ',' || c == ':') {
            if let Some(path) = word.strip_prefix("src/") {
                let rel = format!("{krate}src/{path}");
                if !root().join(&rel).exists() {
                    missing.push(rel);
                }
                if krate == "core/" {
                    core_named.push(path.trim_end_matches('/').to_string());
                }
            }
        }
    }
    assert!(
        missing.is_empty(),
        "the README's layout names {missing:?}, which do not exist"
    );
    let mut unnamed = Vec::new();
    for entry in std::fs::read_dir(root().join("core/src")).unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().into_owned();
        // The crate root and the parsers' test helpers are not steps of the pipeline.
        if name == "lib.rs" || name == "testing.rs" {
            continue;
        }
        let on_map = core_named
            .iter()
            .any(|n| n == &name || n.starts_with(&format!("{name}/")));
        if !on_map {
            unnamed.push(name);
        }
    }
    assert!(
        unnamed.is_empty(),
        "core/src has {unnamed:?}, which the README's layout does not name"
    );
}

/// CONTRIBUTING.md names the files each kind of change touches: every path
/// it names (in backquotes, with a `/`) exists.
#[test]
fn contributing_names_what_exists() {
    let text = read("CONTRIBUTING.md");
    let mut missing = Vec::new();
    let mut named = 0;
    for quoted in text.split('`').skip(1).step_by(2) {
        let looks_like_path = quoted.contains('/')
            && !quoted.contains(' ')
            && (quoted.ends_with(".rs") || quoted.ends_with(".md") || quoted.ends_with('/'));
        if !looks_like_path {
            continue;
        }
        named += 1;
        if !root().join(quoted).exists() {
            missing.push(quoted.to_string());
        }
    }
    assert!(named > 20, "only {named} paths found in CONTRIBUTING.md");
    assert!(
        missing.is_empty(),
        "CONTRIBUTING.md names {missing:?}, which do not exist"
    );
}

/// No module cycle in any crate: among the modules of one parent, the
/// `crate::` and `super::` references of their files form a DAG (a module
/// may use its ancestors and descendants; test-only files are left out).
#[test]
fn no_crate_has_a_module_cycle() {
    let mut cycles = Vec::new();
    for krate in ["core", "coordinator", "worker", "submit", "proto", "bench"] {
        let src = root().join(krate).join("src");
        let mut files = Vec::new();
        rust_files(&src, &mut files);
        let module_of = |f: &Path| -> Vec<String> {
            let rel = f.strip_prefix(&src).unwrap().with_extension("");
            let mut parts: Vec<String> = rel
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            if matches!(
                parts.last().map(String::as_str),
                Some("mod" | "lib" | "main")
            ) {
                parts.pop();
            }
            parts
        };
        let modules: Vec<Vec<String>> = files.iter().map(|f| module_of(f)).collect();
        let mut edges: std::collections::BTreeSet<(Vec<String>, Vec<String>)> = Default::default();
        for (file, from) in files.iter().zip(&modules) {
            let name = file.file_name().unwrap().to_string_lossy();
            if name == "tests.rs" || name.ends_with("_tests.rs") || name == "testing.rs" {
                continue;
            }
            let text = std::fs::read_to_string(file).unwrap();
            for target in references(&text, from) {
                // The longest module the reference is inside of.
                let Some(to) = (1..=target.len())
                    .rev()
                    .map(|n| target[..n].to_vec())
                    .find(|m| modules.contains(m))
                else {
                    continue;
                };
                let common = from.iter().zip(&to).take_while(|(a, b)| a == b).count();
                if common == from.len() || common == to.len() {
                    continue; // an ancestor or a descendant
                }
                edges.insert((from[..=common].to_vec(), to[..=common].to_vec()));
            }
        }
        if let Some(cycle) = find_cycle(&edges) {
            cycles.push(format!("{krate}: {}", cycle.join(" -> ")));
        }
    }
    assert!(cycles.is_empty(), "module cycles: {cycles:#?}");
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module paths `text` (a file of module `here`) names through
/// `crate::` and `super::`, outside comments and before an inline
/// `#[cfg(test)] mod … {` (test modules come last); a `{…}` group gives each
/// of its first names.
fn references(text: &str, here: &[String]) -> Vec<Vec<String>> {
    let ident = |s: &str| -> usize {
        s.find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(s.len())
    };
    let mut out = Vec::new();
    let lines: Vec<&str> = text.lines().collect();
    for (n, line) in lines.iter().enumerate() {
        let next = lines.get(n + 1).map_or("", |l| l.trim());
        if line.trim() == "#[cfg(test)]" && next.starts_with("mod ") && next.ends_with('{') {
            break;
        }
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(i) = rest.find("crate::").or_else(|| rest.find("super::")) {
            let (mut base, mut tail) = if rest[i..].starts_with("crate::") {
                (Vec::new(), &rest[i + 7..])
            } else {
                let mut b = here.to_vec();
                let mut t = &rest[i..];
                while let Some(next) = t.strip_prefix("super::") {
                    b.pop();
                    t = next;
                }
                (b, t)
            };
            loop {
                let n = ident(tail);
                if n == 0 {
                    if let Some(group) = tail.strip_prefix('{') {
                        for item in group.split(',') {
                            let item = item.trim();
                            let n = ident(item);
                            if n > 0 {
                                let mut p = base.clone();
                                p.push(item[..n].to_string());
                                out.push(p);
                            }
                        }
                    }
                    break;
                }
                base.push(tail[..n].to_string());
                match tail[n..].strip_prefix("::") {
                    Some(next) => tail = next,
                    None => break,
                }
            }
            if !base.is_empty() {
                out.push(base);
            }
            rest = &rest[i + 7..];
        }
    }
    out
}

/// A cycle of the directed graph `edges`, if it has one.
fn find_cycle(
    edges: &std::collections::BTreeSet<(Vec<String>, Vec<String>)>,
) -> Option<Vec<String>> {
    fn visit(
        node: &Vec<String>,
        edges: &std::collections::BTreeSet<(Vec<String>, Vec<String>)>,
        path: &mut Vec<Vec<String>>,
        done: &mut std::collections::BTreeSet<Vec<String>>,
    ) -> Option<Vec<String>> {
        if let Some(at) = path.iter().position(|p| p == node) {
            let mut c: Vec<String> = path[at..].iter().map(|m| m.join("::")).collect();
            c.push(node.join("::"));
            return Some(c);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.clone());
        for (_, to) in edges.iter().filter(|(f, _)| f == node) {
            if let Some(c) = visit(to, edges, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(node.clone());
        None
    }
    let mut done = Default::default();
    for (from, _) in edges {
        if let Some(c) = visit(from, edges, &mut Vec::new(), &mut done) {
            return Some(c);
        }
    }
    None
}

/// The systemd unit for spare machines starts the worker with flags the
/// worker has: a renamed flag would leave a service that never starts.
#[test]
fn the_systemd_unit_runs_the_worker_with_flags_it_has() {
    let unit = read("deploy/systemd/trevi-worker.service");
    let exec = unit
        .lines()
        .find_map(|l| l.strip_prefix("ExecStart="))
        .expect("an ExecStart= line");
    let mut words = exec.split_whitespace();
    assert_eq!(words.next(), Some("/usr/local/bin/trevi-worker"));
    let flags: Vec<&str> = words.filter(|w| w.starts_with("--")).collect();
    assert!(!flags.is_empty(), "{exec}");
    let help = Command::new(common::bin("trevi-worker"))
        .arg("--help")
        .output()
        .unwrap();
    assert!(help.status.success());
    let help = String::from_utf8_lossy(&help.stdout);
    for flag in flags {
        // A flag's help line is "--flag <VALUE>" or, for a switch, "--flag"
        // alone.
        let listed = help.lines().any(|l| {
            let l = l.trim_start();
            l == flag || l.starts_with(&format!("{flag} "))
        });
        assert!(listed, "trevi-worker has no {flag}:\n{help}");
    }
}
