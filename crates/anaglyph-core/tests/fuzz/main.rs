//! Fuzzing on the stable toolchain: every parser a user feeds ([`targets::TARGETS`])
//! runs first the inputs that once broke it (`regressions/<target>/`), then seeded
//! mutations of its seeds ([`mutate::Mutator`]) for a bounded time. An input fails
//! when the parser panics, takes over [`MAX_SECONDS_PER_INPUT`], or holds more than
//! [`MAX_PEAK_BYTES`] at once; failures are saved for a regression file.
//!
//! ```text
//! cargo test --release -p anaglyph-core --test fuzz                     # 3 s per target (CI)
//! ANAGLYPH_FUZZ_SECONDS=1800 ANAGLYPH_FUZZ_SEED=7 \
//!   cargo test --release -p anaglyph-core --test fuzz -- --nocapture    # 30 min per target
//! ANAGLYPH_FUZZ_TARGET=npy ...                                          # one target
//! ```

mod mutate;
mod peak_memory;
mod targets;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use targets::{Target, TARGETS};

#[global_allocator]
static ALLOCATOR: peak_memory::Counting = peak_memory::Counting;

/// Most bytes a parser may hold at once on any fuzzed input (they are all small).
const MAX_PEAK_BYTES: usize = 100 << 20;
/// Longest a parser may take on one input (wall time: generous, so that a loaded machine
/// does not report a slow input as a hang).
const MAX_SECONDS_PER_INPUT: f64 = 10.0;

std::thread_local! {
    static LAST_PANIC: std::cell::RefCell<String> = const { std::cell::RefCell::new(String::new()) };
}

fn env_number(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Why one input failed, or None.
fn run_one(target: &Target, input: &[u8], scratch: &Path) -> Option<String> {
    let base = peak_memory::reset();
    let clock = Instant::now();
    let outcome = std::panic::catch_unwind(|| (target.run)(input, scratch));
    let seconds = clock.elapsed().as_secs_f64();
    let peak = peak_memory::peak_above(base);
    if outcome.is_err() {
        return Some(format!(
            "panicked: {}",
            LAST_PANIC.with(|p| p.borrow().clone())
        ));
    }
    if seconds > MAX_SECONDS_PER_INPUT {
        return Some(format!("took {seconds:.1} s"));
    }
    if peak > MAX_PEAK_BYTES {
        return Some(format!("held {} MB at once", peak >> 20));
    }
    None
}

/// Saves a failing input where the report says; returns its path.
fn save_failure(target: &Target, input: &[u8], index: usize) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fuzz-failures");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{}-{index}.bin", target.name));
    std::fs::write(&path, input).unwrap();
    path
}

/// The saved regression inputs of `target`.
fn regressions(target: &Target) -> Vec<(PathBuf, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz/regressions")
        .join(target.name);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let bytes = std::fs::read(&p).unwrap();
            (p, bytes)
        })
        .collect()
}

/// Fuzzes `target` for `budget`; returns (inputs run, failures).
fn fuzz(target: &Target, budget: Duration, seed: u64) -> (usize, Vec<String>) {
    let scratch = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    for (path, input) in regressions(target) {
        if let Some(why) = run_one(target, &input, scratch.path()) {
            failures.push(format!("{}: {why}", path.display()));
        }
    }
    let seeds = (target.seeds)(scratch.path());
    assert!(!seeds.is_empty(), "{}: no seeds", target.name);
    let mut mutator = mutate::Mutator::new(seed);
    let clock = Instant::now();
    let mut runs = 0;
    while clock.elapsed() < budget && failures.len() < 5 {
        let input = mutator.next(&seeds);
        runs += 1;
        if let Some(why) = run_one(target, &input, scratch.path()) {
            let saved = save_failure(target, &input, failures.len());
            failures.push(format!("{why} (input saved as {})", saved.display()));
        }
    }
    (runs, failures)
}

#[test]
fn every_parser_survives_its_regressions_and_mutated_input() {
    let seconds = env_number("ANAGLYPH_FUZZ_SECONDS", 3);
    let seed = env_number("ANAGLYPH_FUZZ_SEED", 1);
    let only = std::env::var("ANAGLYPH_FUZZ_TARGET").ok();
    std::panic::set_hook(Box::new(|info| {
        LAST_PANIC.with(|p| *p.borrow_mut() = info.to_string());
    }));
    let mut report = Vec::new();
    for target in TARGETS
        .iter()
        .filter(|t| only.as_deref().is_none_or(|o| o == t.name))
    {
        let (runs, failures) = fuzz(target, Duration::from_secs(seconds), seed);
        println!(
            "{:<14} {runs:>8} inputs, {} failures",
            target.name,
            failures.len()
        );
        report.extend(
            failures
                .into_iter()
                .map(|f| format!("{}: {f}", target.name)),
        );
    }
    let _ = std::panic::take_hook();
    assert!(
        report.is_empty(),
        "fix each, then move its input into tests/fuzz/regressions/<target>/:\n{}",
        report.join("\n")
    );
}
