//! The table of effects in docs/model/README.md is the catalogue's own (`EffectKind::catalogue_markdown`):
//! a range or a name changed in the code and not in that page fails here.

use jetbench_model::EffectKind;

#[test]
fn the_readme_table_of_effects_is_the_catalogue() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/model/README.md");
    let readme = std::fs::read_to_string(path).expect("docs/model/README.md");
    let table = EffectKind::catalogue_markdown();
    let header = table.lines().next().expect("a header row");
    let start = readme.find(header).unwrap_or_else(|| panic!("docs/model/README.md has no table starting {header:?}"));
    let in_readme: String =
        readme[start..].lines().take_while(|l| l.starts_with('|')).map(|l| format!("{l}\n")).collect();
    assert_eq!(
        in_readme, table,
        "the table of effects in docs/model/README.md differs from EffectKind::catalogue_markdown(); paste:\n{table}"
    );
}
