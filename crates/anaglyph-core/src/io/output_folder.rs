//! Transactional output folders. A command that writes a folder (`reconstruct`,
//! `simulate`, `demo`) opens an [`OutputFolder`] before any work: the target is checked
//! (a folder anaglyph wrote is replaced whole; anything else is refused without
//! `--force`; a folder holding the command's own inputs is always refused), and the files
//! go into a hidden sibling `.NAME.partial-PID`. [`OutputFolder::commit`] renames the
//! finished folder into place, so after a kill at any moment the target is the previous
//! complete folder or absent, never a mix of two runs. Leftovers of killed runs are
//! removed by the next run into the same place.
//!
//! The manifest each command writes last lists every file with its size and CRC-32
//! ([`FileRecord`], from [`OutputFolder::inventory`]); [`verify_output_folder`] is what
//! readers such as `anaglyph eval` call to refuse a stale, partial or mixed folder.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::io::Read;
use std::path::{Path, PathBuf};

/// The file every anaglyph output folder holds, written last.
pub const MANIFEST: &str = "manifest.json";

/// Whether a target that anaglyph did not write may be replaced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Replace {
    /// Replace an empty folder or one anaglyph wrote; refuse anything else.
    OwnOutput,
    /// Replace whatever folder is there (`--force`).
    Anything,
}

/// One file of an output folder, as its manifest records it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileRecord {
    /// Relative to the folder, with `/` separators.
    pub path: String,
    pub bytes: u64,
    /// CRC-32 (IEEE) of the contents, as 8 hex digits.
    pub crc32: String,
}

/// A folder being written: files go under [`OutputFolder::path`] until
/// [`OutputFolder::commit`]; dropped without a commit, it leaves the target as it was.
#[derive(Debug)]
pub struct OutputFolder {
    target: PathBuf,
    staging: PathBuf,
    run_id: String,
    committed: bool,
}

impl OutputFolder {
    /// Checks that `target` may be (re)placed and that no path in `inputs` lies inside it,
    /// removes what killed runs left beside it, and creates the staging folder, so an
    /// unwritable place fails here, before any work.
    pub fn begin(target: &Path, replace: Replace, inputs: &[&Path]) -> Result<Self> {
        let name = folder_name(target)?;
        let parent = parent_of(target);
        check_target(target, replace, inputs)?;
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        remove_stale_siblings(parent, &name);
        let pid = std::process::id();
        let staging = parent.join(format!(".{name}.partial-{pid}"));
        // Errors name the folder asked for, not the hidden staging folder beside it.
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(|e| Error::io(target, e))?;
        }
        std::fs::create_dir(&staging).map_err(|e| Error::io(target, e))?;
        Ok(OutputFolder {
            target: target.to_path_buf(),
            staging,
            run_id: new_run_id(),
            committed: false,
        })
    }

    /// Where the files go until the commit.
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// The folder's name once committed.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// A name for this run, unique across runs, recorded in the manifest.
    pub fn run_id(&self) -> &str {
        &self.run_id
    }

    /// Every file written so far (the manifest excepted), sorted by path, with its size
    /// and CRC-32: what the manifest lists.
    pub fn inventory(&self) -> Result<Vec<FileRecord>> {
        let mut records = Vec::new();
        for relative in files_under(&self.staging)? {
            if relative != MANIFEST {
                records.push(record_of(&self.staging, &relative)?);
            }
        }
        Ok(records)
    }

    /// Writes `manifest` (a struct or map serialising to a JSON object) as the folder's
    /// `manifest.json`, with `run_id` and `files` (every file written so far) added;
    /// call it last. Returns the number of files the folder holds, the manifest included.
    pub fn write_manifest(&self, manifest: &impl Serialize) -> Result<usize> {
        let mut value = serde_json::to_value(manifest).map_err(|e| Error::output(MANIFEST, e))?;
        let files = self.inventory()?;
        let count = files.len() + 1;
        let object = value
            .as_object_mut()
            .ok_or_else(|| Error::output(MANIFEST, "the manifest is not a JSON object (a bug)"))?;
        // What marks the folder as anaglyph's, for the next run into it.
        object
            .entry("generator")
            .or_insert_with(|| format!("anaglyph {}", env!("CARGO_PKG_VERSION")).into());
        object.insert("run_id".into(), self.run_id.clone().into());
        let files = serde_json::to_value(files).map_err(|e| Error::output(MANIFEST, e))?;
        object.insert("files".into(), files);
        let json = serde_json::to_string_pretty(&value).map_err(|e| Error::output(MANIFEST, e))?;
        let path = self.staging.join(MANIFEST);
        std::fs::write(&path, json).map_err(|e| Error::io(&path, e))?;
        Ok(count)
    }

    /// Renames the finished folder into place (the previous one, if any, is moved aside
    /// first and then removed); returns the target.
    pub fn commit(mut self) -> Result<PathBuf> {
        let name = folder_name(&self.target)?;
        let aside = parent_of(&self.target).join(format!(".{name}.old-{}", std::process::id()));
        let had_previous = self.target.exists();
        if had_previous {
            std::fs::rename(&self.target, &aside).map_err(|e| Error::io(&self.target, e))?;
        }
        if let Err(e) = std::fs::rename(&self.staging, &self.target) {
            if had_previous {
                let _ = std::fs::rename(&aside, &self.target);
            }
            return Err(Error::io(&self.target, e));
        }
        self.committed = true;
        if had_previous {
            let _ = std::fs::remove_dir_all(&aside);
        }
        Ok(self.target.clone())
    }
}

impl Drop for OutputFolder {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
    }
}

/// An [`Error::Output`] naming the target folder.
fn refuse(target: &Path, message: impl ToString) -> Error {
    Error::output(target.display().to_string(), message)
}

fn folder_name(target: &Path) -> Result<String> {
    match target.file_name() {
        Some(name) => Ok(name.to_string_lossy().into_owned()),
        None => Err(refuse(
            target,
            "no folder name (expected a path such as out/ or results/run1)",
        )),
    }
}

fn parent_of(target: &Path) -> &Path {
    match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The refusals of [`OutputFolder::begin`], each naming what was found.
fn check_target(target: &Path, replace: Replace, inputs: &[&Path]) -> Result<()> {
    if !target.exists() {
        return Ok(());
    }
    if !target.is_dir() {
        return Err(refuse(
            target,
            "is a file; expected a folder to write into (or a path that does not exist)",
        ));
    }
    let absolute = std::fs::canonicalize(target).map_err(|e| Error::io(target, e))?;
    let cwd = std::env::current_dir().map_err(|e| Error::io(".", e))?;
    if cwd.starts_with(&absolute) {
        return Err(refuse(
            target,
            "is the working folder or one above it; expected a folder of its own",
        ));
    }
    for input in inputs {
        if let Ok(input) = std::fs::canonicalize(input) {
            if input.starts_with(&absolute) {
                return Err(refuse(
                    target,
                    format!(
                        "holds the input {}, which replacing it would delete; \
                         expected a folder apart from the inputs",
                        input.display()
                    ),
                ));
            }
        }
    }
    if replace == Replace::OwnOutput {
        if let Some(foreign) = foreign_entry(target)? {
            return Err(refuse(
                target,
                format!(
                    "{foreign}; anaglyph replaces only a folder it wrote, whole: choose another \
                     folder, move that away, or pass --force to replace the folder whole"
                ),
            ));
        }
    }
    Ok(())
}

/// Why `dir` is not anaglyph's to replace (None: it is empty, or holds exactly what its
/// anaglyph manifest lists): no anaglyph manifest, or the first entry the manifest does
/// not list (a file or folder a user added, hidden ones included).
fn foreign_entry(dir: &Path) -> Result<Option<String>> {
    let mut entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    if entries.next().is_none() {
        return Ok(None);
    }
    let manifest = std::fs::read_to_string(dir.join(MANIFEST))
        .ok()
        .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok());
    let Some(manifest) = manifest.filter(|m| {
        m.get("generator")
            .and_then(|g| g.as_str())
            .is_some_and(|g| g.starts_with("anaglyph"))
    }) else {
        return Ok(Some(
            "holds files anaglyph did not write (no anaglyph manifest.json)".into(),
        ));
    };
    let listed: std::collections::BTreeSet<String> = manifest
        .get("files")
        .and_then(|f| f.as_array())
        .map(|files| {
            files
                .iter()
                .filter_map(|f| f.get("path")?.as_str().map(str::to_owned))
                .collect()
        })
        .unwrap_or_default();
    let mut pending = vec![(dir.to_path_buf(), String::new())];
    while let Some((folder, prefix)) = pending.pop() {
        let entries = std::fs::read_dir(&folder).map_err(|e| Error::io(&folder, e))?;
        let mut names: Vec<_> = entries.flatten().collect();
        names.sort_by_key(|e| e.file_name());
        for entry in names {
            let relative = format!("{prefix}{}", entry.file_name().to_string_lossy());
            let is_dir = entry
                .file_type()
                .map_err(|e| Error::io(entry.path(), e))?
                .is_dir();
            if is_dir {
                let inside = format!("{relative}/");
                if !listed.iter().any(|f| f.starts_with(&inside)) {
                    return Ok(Some(format!(
                        "holds {relative}/, which its manifest does not list (not anaglyph's)"
                    )));
                }
                pending.push((entry.path(), inside));
            } else if relative != MANIFEST && !listed.contains(&relative) {
                return Ok(Some(format!(
                    "holds {relative}, which its manifest does not list (not anaglyph's)"
                )));
            }
        }
    }
    Ok(None)
}

/// Removes `.NAME.partial-PID` and `.NAME.old-PID` folders of processes that no longer
/// run (runs that were killed). Best effort: what cannot be removed stays.
fn remove_stale_siblings(parent: &Path, name: &str) {
    for kind in [".partial-", ".old-"] {
        remove_leftovers_of_dead_runs(parent, &format!(".{name}{kind}"));
    }
}

/// Removes every `PREFIX{pid}` entry of `dir`, file or folder, whose process no longer
/// runs: what a killed run left. Best effort: what cannot be removed stays.
pub(crate) fn remove_leftovers_of_dead_runs(dir: &Path, prefix: &str) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let pid = name
            .strip_prefix(prefix)
            .and_then(|p| p.parse::<u32>().ok());
        if pid.is_some_and(|pid| !process_is_running(pid)) {
            let path = entry.path();
            let _ = if path.is_dir() {
                std::fs::remove_dir_all(&path)
            } else {
                std::fs::remove_file(&path)
            };
        }
    }
}

/// Whether process `pid` runs, where the system says (`/proc`); elsewhere assumed to
/// run, so that nothing another run is writing is ever removed.
fn process_is_running(pid: u32) -> bool {
    if pid == std::process::id() || !Path::new("/proc/self").exists() {
        return true;
    }
    Path::new(&format!("/proc/{pid}")).exists()
}

fn new_run_id() -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    format!("{nanos:x}-{:x}", std::process::id())
}

/// Every file under `dir` (hidden ones excepted), relative, with `/` separators, sorted.
fn files_under(dir: &Path) -> Result<Vec<String>> {
    let mut found = Vec::new();
    let mut pending = vec![(dir.to_path_buf(), String::new())];
    while let Some((folder, prefix)) = pending.pop() {
        let entries = std::fs::read_dir(&folder).map_err(|e| Error::io(&folder, e))?;
        for entry in entries {
            let entry = entry.map_err(|e| Error::io(&folder, e))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') {
                continue;
            }
            let relative = format!("{prefix}{name}");
            let kind = entry.file_type().map_err(|e| Error::io(entry.path(), e))?;
            if kind.is_dir() {
                pending.push((entry.path(), format!("{relative}/")));
            } else {
                found.push(relative);
            }
        }
    }
    found.sort();
    Ok(found)
}

fn record_of(dir: &Path, relative: &str) -> Result<FileRecord> {
    let path = dir.join(relative);
    let mut file = std::fs::File::open(&path).map_err(|e| Error::io(&path, e))?;
    let mut hasher = crc32fast::Hasher::new();
    let mut buffer = vec![0u8; 1 << 20];
    let mut bytes = 0u64;
    loop {
        let n = file.read(&mut buffer).map_err(|e| Error::io(&path, e))?;
        if n == 0 {
            break;
        }
        hasher.update(&buffer[..n]);
        bytes += n as u64;
    }
    Ok(FileRecord {
        path: relative.to_owned(),
        bytes,
        crc32: format!("{:08x}", hasher.finalize()),
    })
}

#[derive(Deserialize)]
struct ManifestFiles {
    generator: String,
    run_id: String,
    files: Vec<FileRecord>,
}

/// What [`verify_output_folder`] found: the run that wrote the folder.
#[derive(Debug, Clone)]
pub struct VerifiedFolder {
    pub generator: String,
    pub run_id: String,
    pub files: Vec<FileRecord>,
}

/// Checks that `dir` is one complete anaglyph output: its manifest exists and lists
/// files, every listed file is there with the recorded size and CRC-32, and no file is
/// there that the manifest does not list (a file of another run).
pub fn verify_output_folder(dir: &Path) -> Result<VerifiedFolder> {
    verify_files(dir, "")
}

/// As [`verify_output_folder`] for the files under `dir/sub/` only (a simulation's
/// `truth/`), so that a user may edit the rest (its `rig.toml`) and still use the truth.
pub fn verify_output_subfolder(dir: &Path, sub: &str) -> Result<VerifiedFolder> {
    verify_files(dir, &format!("{}/", sub.trim_end_matches('/')))
}

/// The checks of [`verify_output_folder`] on the files whose path starts with `scope`.
fn verify_files(dir: &Path, scope: &str) -> Result<VerifiedFolder> {
    let manifest_path = dir.join(MANIFEST);
    if !manifest_path.is_file() {
        return Err(Error::MissingFile {
            path: manifest_path,
            what: "the record of a complete anaglyph output folder (a run that was \
                      killed, or a folder anaglyph did not write, has none)"
                .into(),
        });
    }
    let text = std::fs::read_to_string(&manifest_path).map_err(|e| Error::io(&manifest_path, e))?;
    let manifest: ManifestFiles = serde_json::from_str(&text).map_err(|e| {
        Error::decode(
            &manifest_path,
            format!("{e}; expected generator, run_id and files with path, bytes and crc32 (written by an older anaglyph? re-run it)"),
        )
    })?;
    let listed: std::collections::BTreeSet<&str> =
        manifest.files.iter().map(|f| f.path.as_str()).collect();
    for record in manifest.files.iter().filter(|f| f.path.starts_with(scope)) {
        let found = record_of(dir, &record.path).map_err(|_| Error::MissingFile {
            path: dir.join(&record.path),
            what: format!("listed in {} (a partial folder)", manifest_path.display()),
        })?;
        if found != *record {
            return Err(Error::output_conflict(
                dir.join(&record.path).display().to_string(),
                format!("{} bytes, CRC-32 {}", found.bytes, found.crc32),
                format!(
                    "{} bytes, CRC-32 {} as the manifest records (the file changed after run {})",
                    record.bytes, record.crc32, manifest.run_id
                ),
            ));
        }
    }
    for relative in files_under(dir)? {
        let in_scope = relative.starts_with(scope);
        if in_scope && relative != MANIFEST && !listed.contains(relative.as_str()) {
            return Err(Error::output_conflict(
                dir.join(&relative).display().to_string(),
                "a file the manifest does not list",
                format!(
                    "only the files of run {} (a file of another run?)",
                    manifest.run_id
                ),
            ));
        }
    }
    Ok(VerifiedFolder {
        generator: manifest.generator,
        run_id: manifest.run_id,
        files: manifest.files,
    })
}

#[cfg(test)]
mod tests;
