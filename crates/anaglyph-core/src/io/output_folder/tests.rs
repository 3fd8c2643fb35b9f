use super::*;

/// Writes `files` and a manifest listing them into `folder`, then commits it.
fn finish(folder: OutputFolder, files: &[(&str, &str)]) -> PathBuf {
    for (path, text) in files {
        let path = folder.path().join(path);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text).unwrap();
    }
    let count = folder
        .write_manifest(&serde_json::json!({"generator": "anaglyph test"}))
        .unwrap();
    assert_eq!(count, files.len() + 1);
    folder.commit().unwrap()
}

fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn a_committed_folder_verifies_and_leaves_nothing_beside_it() {
    let root = tempfile::tempdir().unwrap();
    let target = root.path().join("out");
    let folder = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    assert!(!target.exists(), "nothing appears before the commit");
    finish(folder, &[("views/a.img", "cube"), ("b.txt", "note")]);
    let verified = verify_output_folder(&target).unwrap();
    let paths: Vec<&str> = verified.files.iter().map(|f| f.path.as_str()).collect();
    assert_eq!(paths, ["b.txt", "views/a.img"]);
    assert_eq!(verified.files[0].bytes, 4);
    assert_eq!(names_in(root.path()), ["out"]);
}

#[test]
fn a_run_dropped_before_its_commit_leaves_the_previous_folder_whole() {
    let root = tempfile::tempdir().unwrap();
    let target = root.path().join("out");
    let first = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    finish(
        first,
        &[("views/r0c0.img", "old0"), ("views/r0c1.img", "old1")],
    );
    let second = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    std::fs::create_dir(second.path().join("views")).unwrap();
    std::fs::write(second.path().join("views/r0c0.img"), "new0").unwrap();
    drop(second);
    assert_eq!(names_in(root.path()), ["out"]);
    verify_output_folder(&target).unwrap();
    assert_eq!(
        std::fs::read(target.join("views/r0c0.img")).unwrap(),
        b"old0"
    );
}

#[test]
fn a_rerun_replaces_its_own_folder_whole() {
    let root = tempfile::tempdir().unwrap();
    let target = root.path().join("out");
    let first = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    finish(
        first,
        &[("views/r0c0.img", "old0"), ("views/r0c1.img", "old1")],
    );
    let second = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    finish(second, &[("views/r0c0.img", "new0")]);
    assert_eq!(names_in(&target.join("views")), ["r0c0.img"]);
    verify_output_folder(&target).unwrap();
    assert_eq!(names_in(root.path()), ["out"]);
}

#[test]
fn files_a_user_added_to_an_anaglyph_folder_are_never_deleted() {
    let root = tempfile::tempdir().unwrap();
    let target = root.path().join("out");
    let first = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    finish(first, &[("views/r0c0.img", "old0")]);
    for (added, named) in [
        ("NOTES.txt", "NOTES.txt"),
        ("mine/data.csv", "mine/"),
        ("views/extra.csv", "views/extra.csv"),
        (".hidden", ".hidden"),
    ] {
        let path = target.join(added);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, "user's").unwrap();
        let refused = OutputFolder::begin(&target, Replace::OwnOutput, &[]);
        let message = refused.err().map(|e| e.to_string()).unwrap_or_default();
        assert!(message.contains(named), "{added}: {message}");
        assert_eq!(std::fs::read(&path).unwrap(), b"user's");
        std::fs::remove_file(&path).unwrap();
        if added.starts_with("mine/") {
            std::fs::remove_dir(target.join("mine")).unwrap();
        }
    }
    // An empty folder a user made inside is theirs too.
    std::fs::create_dir(target.join("empty")).unwrap();
    assert!(OutputFolder::begin(&target, Replace::OwnOutput, &[]).is_err());
    std::fs::remove_dir(target.join("empty")).unwrap();
    // As anaglyph left it, the folder is replaced.
    let second = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    finish(second, &[("views/r0c0.img", "new0")]);
}

#[test]
fn a_manifest_without_a_generator_still_marks_the_folder_as_anaglyph_s() {
    let root = tempfile::tempdir().unwrap();
    let target = root.path().join("calib");
    let first = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    std::fs::write(first.path().join("r0c0.json"), "{}").unwrap();
    first
        .write_manifest(&serde_json::json!({"pattern": "9x6"}))
        .unwrap();
    first.commit().unwrap();
    let again = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    drop(again);
}

#[test]
fn a_folder_anaglyph_did_not_write_is_refused_without_force() {
    let root = tempfile::tempdir().unwrap();
    let target = root.path().join("thesis");
    std::fs::create_dir(&target).unwrap();
    std::fs::write(target.join("chapter1.tex"), "words").unwrap();
    let refused = OutputFolder::begin(&target, Replace::OwnOutput, &[]);
    assert_eq!(refused.err().map(|e| e.kind()), Some("Output"));
    assert_eq!(
        names_in(root.path()),
        ["thesis"],
        "nothing staged when refused"
    );
    let forced = OutputFolder::begin(&target, Replace::Anything, &[]).unwrap();
    finish(forced, &[("a.txt", "x")]);
    assert_eq!(names_in(&target), ["a.txt", "manifest.json"]);
}

#[test]
fn a_folder_holding_an_input_or_a_file_is_refused_even_with_force() {
    let root = tempfile::tempdir().unwrap();
    let target = root.path().join("sim");
    let folder = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    finish(folder, &[("rig.toml", "rows = 1")]);
    let rig = target.join("rig.toml");
    let refused = OutputFolder::begin(&target, Replace::Anything, &[&rig]);
    assert_eq!(refused.err().map(|e| e.kind()), Some("Output"));
    let refused = OutputFolder::begin(&rig, Replace::Anything, &[]);
    assert_eq!(refused.err().map(|e| e.kind()), Some("Output"));
    verify_output_folder(&target).unwrap();
}

#[test]
fn leftovers_of_killed_runs_are_removed_and_live_ones_kept() {
    let root = tempfile::tempdir().unwrap();
    let dead = root.path().join(".out.partial-4294967295");
    let dead_aside = root.path().join(".out.old-4294967294");
    let other_name = root.path().join(".other.partial-4294967295");
    for dir in [&dead, &dead_aside, &other_name] {
        std::fs::create_dir(dir).unwrap();
        std::fs::write(dir.join("x"), "half").unwrap();
    }
    let folder = OutputFolder::begin(&root.path().join("out"), Replace::OwnOutput, &[]).unwrap();
    let staging = folder
        .path()
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let mut expected = vec![".other.partial-4294967295".to_owned(), staging];
    expected.sort();
    assert_eq!(names_in(root.path()), expected);
}

#[test]
fn verification_refuses_partial_mixed_and_changed_folders() {
    let root = tempfile::tempdir().unwrap();
    let target = root.path().join("out");
    let folder = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    finish(folder, &[("views/r0c0.img", "cube0")]);
    std::fs::write(target.join("views/r0c1.img"), "stale").unwrap();
    let mixed = verify_output_folder(&target);
    assert_eq!(mixed.err().map(|e| e.kind()), Some("OutputConflict"));
    std::fs::remove_file(target.join("views/r0c1.img")).unwrap();
    std::fs::write(target.join("views/r0c0.img"), "cube9").unwrap();
    let changed = verify_output_folder(&target);
    assert_eq!(changed.err().map(|e| e.kind()), Some("OutputConflict"));
    std::fs::remove_file(target.join("views/r0c0.img")).unwrap();
    let partial = verify_output_folder(&target);
    assert_eq!(partial.err().map(|e| e.kind()), Some("MissingFile"));
    std::fs::remove_file(target.join(MANIFEST)).unwrap();
    let unfinished = verify_output_folder(&target);
    assert_eq!(unfinished.err().map(|e| e.kind()), Some("MissingFile"));
}

#[test]
fn a_subfolder_verifies_while_the_rest_was_edited() {
    let root = tempfile::tempdir().unwrap();
    let target = root.path().join("sim");
    let folder = OutputFolder::begin(&target, Replace::OwnOutput, &[]).unwrap();
    finish(
        folder,
        &[("rig.toml", "rows = 2"), ("truth/r0c0.pfm", "map")],
    );
    std::fs::write(target.join("rig.toml"), "rows = 2 # edited").unwrap();
    assert_eq!(
        verify_output_folder(&target).err().map(|e| e.kind()),
        Some("OutputConflict")
    );
    verify_output_subfolder(&target, "truth").unwrap();
    std::fs::write(target.join("truth/r0c1.pfm"), "stale").unwrap();
    assert_eq!(
        verify_output_subfolder(&target, "truth")
            .err()
            .map(|e| e.kind()),
        Some("OutputConflict")
    );
}
