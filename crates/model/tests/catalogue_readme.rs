//! The README's table of effects is the catalogue's own (`EffectKind::catalogue_markdown`):
//! a range or a name changed in the code and not in the README fails here.

use jetbench_model::EffectKind;

#[test]
fn the_readme_table_of_effects_is_the_catalogue() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../README.md");
    let readme = std::fs::read_to_string(path).expect("the repository's README");
    let table = EffectKind::catalogue_markdown();
    let header = table.lines().next().expect("a header row");
    let start = readme.find(header).unwrap_or_else(|| panic!("README has no table starting {header:?}"));
    let in_readme: String =
        readme[start..].lines().take_while(|l| l.starts_with('|')).map(|l| format!("{l}\n")).collect();
    assert_eq!(
        in_readme, table,
        "README's table of effects differs from EffectKind::catalogue_markdown(); paste:\n{table}"
    );
}
