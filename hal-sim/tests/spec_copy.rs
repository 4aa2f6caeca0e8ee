//! `docs/session-log.md` carries the shared session-log spec verbatim between its BEGIN and
//! END markers. The shared spec lives beside the clone (`../shared/spec/session-log.md`,
//! or `$ARVA_SHARED/spec/session-log.md`); without it this test says so and passes.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use std::path::PathBuf;

const BEGIN: &str = "<!-- BEGIN shared spec -->\n";
const END: &str = "<!-- END shared spec -->\n";

fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("hal-sim sits in the workspace")
        .to_path_buf()
}

/// The part of the repository's copy between the markers.
fn copied_part(doc: &str) -> Option<&str> {
    let start = doc.find(BEGIN)? + BEGIN.len();
    let len = doc[start..].find(END)?;
    Some(&doc[start..start + len])
}

#[test]
fn docs_copy_equals_the_shared_spec() {
    let doc = std::fs::read_to_string(repo_root().join("docs/session-log.md"))
        .expect("docs/session-log.md exists");
    let copy = copied_part(&doc).expect("docs/session-log.md has the BEGIN and END markers");
    assert!(
        copy.contains("# Session log format (`arva-session`, version 1)"),
        "the copied part is the session-log spec"
    );
    let shared = std::env::var_os("ARVA_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join("../shared"))
        .join("spec/session-log.md");
    let Ok(spec) = std::fs::read_to_string(&shared) else {
        eprintln!(
            "SKIPPED: {} not found (set ARVA_SHARED to the shared directory to compare)",
            shared.display()
        );
        return;
    };
    assert!(
        copy == spec,
        "docs/session-log.md differs from {}: copy the shared spec between the markers",
        shared.display()
    );
}

#[test]
fn the_marker_search_finds_only_what_is_between() {
    let doc = format!("intro\n{BEGIN}spec text\n{END}own part\n");
    assert_eq!(copied_part(&doc), Some("spec text\n"));
    assert_eq!(copied_part("no markers"), None);
}
