//! `gardefou filter rewrite` on the sorting line, with the model learned from the
//! shipped normal run (`diagnoser/tests/fixtures/diagnosis/sorting-model.json`).

use std::path::Path;
use std::process::{Command, Output};

fn gardefou(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gardefou"))
        .args(args)
        .output()
        .expect("runs the binary")
}

fn path(rel: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(rel)
        .display()
        .to_string()
}

fn rewrite(extra: &[&str]) -> Output {
    let plant = path("datasets/plants/sorting.toml");
    let model = path("diagnoser/tests/fixtures/diagnosis/sorting-model.json");
    let mut args = vec!["filter", "rewrite", "--plant", &plant, "--model", &model];
    args.extend_from_slice(extra);
    gardefou(&args)
}

#[test]
fn def_c4_rewrites_the_constraints_that_read_c4_conservatively() {
    let o = rewrite(&["--flags", "def_C4"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    // Seed 002 eq. 30: C4 read positively takes every interval where it may be 1.
    assert!(
        text.lines()
            .any(|l| l == "CSs6 = (!def_C4 & C4 | def_C4 & (I1 | I10 | I2 | I9)) & C6 & A2"),
        "{text}"
    );
    // Read negatively, only the intervals where C4 is certainly 1.
    assert!(
        text.lines()
            .any(|l| l == "CSs14 = !(!def_C4 & C4 | def_C4 & (I1 | I10)) & RE(A4)"),
        "{text}"
    );
    // Constraints that do not read C4 are not printed.
    assert!(!text.contains("CSs5 ="), "{text}");
}

#[test]
fn suspects_and_bad_flags() {
    let o = rewrite(&["--flags", "def_C5", "--suspects"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.lines()
            .any(|l| l.starts_with("CSs5 = ") && l.contains("def_C5 | suspect_C5")),
        "{text}"
    );
    let o = rewrite(&["--flags", "def_C9"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("def_C9"), "{err}");
}
