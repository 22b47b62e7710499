//! The repository's layout rules, checked on its own sources (see `docs/testing.md`):
//!
//! * no function outside tests is longer than [`MAX_FN_LINES`] lines, and no line outside tests
//!   is wider than [`MAX_LINE_WIDTH`] characters;
//! * every public type name (struct, enum, trait, type alias, union) means one thing: it is
//!   defined in one place in the workspace;
//! * the product speaks of the product: no issue numbers, development sessions or stops in the
//!   README, the book or the sources, and no reference to files outside the repository;
//! * the README and every crate's README stay short, and every relative link in them and in
//!   the book resolves.
//!
//! Each rule reads the files as they are on disk, so a change that breaks one fails here with
//! the places named.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use syn::spanned::Spanned;
use syn::visit::Visit;

/// The longest a function outside tests may be, from its first attribute or doc comment to
/// its closing brace.
const MAX_FN_LINES: usize = 60;
/// The widest a line outside tests may be (rustfmt's width, `rustfmt.toml`).
const MAX_LINE_WIDTH: usize = 100;
/// The longest the README may be.
const MAX_README_LINES: usize = 300;
/// The longest a crate's README may be: what the crate is for and where things are.
const MAX_CRATE_README_LINES: usize = 150;
/// The crates whose `src/` the rules read.
const CRATES: [&str; 12] = [
    "protocol",
    "robot-model",
    "robot-agent",
    "coordinator",
    "sim-bridge",
    "planner",
    "scenario",
    "evaluation",
    "launch",
    "experiments",
    "runner",
    "tests",
];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace root").to_path_buf()
}

/// Every file under `dir` whose name ends in `ext`, sorted.
fn files(dir: &Path, ext: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = fs::read_dir(&d) else { continue };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.to_string_lossy().ends_with(ext) {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// Every `.rs` file of the crates' `src/` folders (tests, benches and examples are not read).
fn sources() -> Vec<(PathBuf, syn::File)> {
    let root = root();
    CRATES
        .iter()
        .flat_map(|c| files(&root.join(c).join("src"), ".rs"))
        .map(|p| {
            let text = fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            let file = syn::parse_file(&text).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            (p.strip_prefix(&root).unwrap().to_path_buf(), file)
        })
        .collect()
}

fn is_test_only(attrs: &[syn::Attribute]) -> bool {
    attrs.iter().any(|a| match &a.meta {
        syn::Meta::Path(p) => p.is_ident("test"),
        syn::Meta::List(l) if l.path.is_ident("cfg") => {
            let cond = l.tokens.to_string();
            cond == "test" || cond.starts_with("all (test") || cond.starts_with("all(test")
        }
        _ => false,
    })
}

/// Functions longer than [`MAX_FN_LINES`], outside `#[cfg(test)]` modules and `#[test]`s.
#[derive(Default)]
struct LongFunctions {
    file: PathBuf,
    found: Vec<String>,
}

impl LongFunctions {
    fn check(&mut self, name: &syn::Ident, span: proc_macro2::Span) {
        let lines = span.end().line - span.start().line + 1;
        if lines > MAX_FN_LINES {
            self.found.push(format!(
                "{}:{} fn {name}: {lines} lines",
                self.file.display(),
                span.start().line
            ));
        }
    }
}

impl<'a> Visit<'a> for LongFunctions {
    fn visit_item_mod(&mut self, m: &'a syn::ItemMod) {
        if !is_test_only(&m.attrs) {
            syn::visit::visit_item_mod(self, m);
        }
    }
    fn visit_item_fn(&mut self, f: &'a syn::ItemFn) {
        if !is_test_only(&f.attrs) {
            self.check(&f.sig.ident, f.span());
            syn::visit::visit_item_fn(self, f);
        }
    }
    fn visit_item_impl(&mut self, i: &'a syn::ItemImpl) {
        if !is_test_only(&i.attrs) {
            syn::visit::visit_item_impl(self, i);
        }
    }
    fn visit_impl_item_fn(&mut self, f: &'a syn::ImplItemFn) {
        if !is_test_only(&f.attrs) {
            self.check(&f.sig.ident, f.span());
            syn::visit::visit_impl_item_fn(self, f);
        }
    }
    fn visit_trait_item_fn(&mut self, f: &'a syn::TraitItemFn) {
        if f.default.is_some() {
            self.check(&f.sig.ident, f.span());
        }
        syn::visit::visit_trait_item_fn(self, f);
    }
}

/// The functions of `file` (read from `path`) longer than [`MAX_FN_LINES`].
fn long_functions(path: PathBuf, file: &syn::File) -> Vec<String> {
    let mut v = LongFunctions { file: path, found: Vec::new() };
    v.visit_file(file);
    v.found
}

#[test]
fn no_function_outside_tests_is_longer_than_a_screen() {
    let long: Vec<String> =
        sources().into_iter().flat_map(|(p, f)| long_functions(p, &f)).collect();
    assert!(
        long.is_empty(),
        "{} functions over {MAX_FN_LINES} lines:\n{}",
        long.len(),
        long.join("\n")
    );
}

/// A source file with one function of `lines` lines (a doc comment, the signature, a body of
/// statements and the closing brace), and a test-only one twice as long.
fn function_of(lines: usize) -> syn::File {
    let body: String = (0..lines - 3).map(|i| format!("    let _x{i} = {i};\n")).collect();
    let test_body: String = (0..2 * lines).map(|i| format!("    let _y{i} = {i};\n")).collect();
    let text = format!(
        "/// A function.\nfn f() {{\n{body}}}\n#[cfg(test)]\nmod tests {{\nfn g() {{\n{test_body}}}\n}}\n"
    );
    syn::parse_file(&text).expect("a function of the given length")
}

#[test]
fn the_function_length_rule_can_fail() {
    let at_limit = long_functions(PathBuf::from("a.rs"), &function_of(MAX_FN_LINES));
    assert!(at_limit.is_empty(), "{at_limit:?}");
    let over = long_functions(PathBuf::from("a.rs"), &function_of(MAX_FN_LINES + 1));
    assert_eq!(over, vec![format!("a.rs:1 fn f: {} lines", MAX_FN_LINES + 1)]);
}

/// Lines of `text` wider than [`MAX_LINE_WIDTH`] characters before its `#[cfg(test)]` module
/// (the tests come last in a file of this workspace), as `line: width`.
fn wide_lines(text: &str) -> Vec<String> {
    text.lines()
        .take_while(|l| l.trim() != "#[cfg(test)]")
        .enumerate()
        .filter(|(_, l)| l.chars().count() > MAX_LINE_WIDTH)
        .map(|(i, l)| format!("{}: {}", i + 1, l.chars().count()))
        .collect()
}

#[test]
fn no_line_outside_tests_is_wider_than_rustfmts_width() {
    let root = root();
    let mut wide = Vec::new();
    for p in CRATES.iter().flat_map(|c| files(&root.join(c).join("src"), ".rs")) {
        let text = fs::read_to_string(&p).unwrap_or_default();
        let name = p.strip_prefix(&root).unwrap().display().to_string();
        wide.extend(wide_lines(&text).into_iter().map(|w| format!("{name}:{w}")));
    }
    assert!(
        wide.is_empty(),
        "{} lines over {MAX_LINE_WIDTH} characters:\n{}",
        wide.len(),
        wide.join("\n")
    );
}

#[test]
fn the_line_width_rule_can_fail() {
    let wide = "x".repeat(MAX_LINE_WIDTH + 1);
    let text = format!("fn f() {{}}\n{wide}\n#[cfg(test)]\nmod tests {{\n// {wide}\n}}\n");
    assert_eq!(wide_lines(&text), vec![format!("2: {}", MAX_LINE_WIDTH + 1)]);
    assert!(wide_lines(&"x".repeat(MAX_LINE_WIDTH)).is_empty());
}

/// Public type names and where each is defined.
#[derive(Default)]
struct PublicTypes {
    file: PathBuf,
    names: BTreeMap<String, Vec<String>>,
}

impl PublicTypes {
    fn add(&mut self, vis: &syn::Visibility, name: &syn::Ident) {
        if matches!(vis, syn::Visibility::Public(_) | syn::Visibility::Restricted(_)) {
            self.names.entry(name.to_string()).or_default().push(self.file.display().to_string());
        }
    }
}

impl<'a> Visit<'a> for PublicTypes {
    fn visit_item_mod(&mut self, m: &'a syn::ItemMod) {
        if !is_test_only(&m.attrs) {
            syn::visit::visit_item_mod(self, m);
        }
    }
    fn visit_item_struct(&mut self, i: &'a syn::ItemStruct) {
        self.add(&i.vis, &i.ident);
    }
    fn visit_item_enum(&mut self, i: &'a syn::ItemEnum) {
        self.add(&i.vis, &i.ident);
    }
    fn visit_item_trait(&mut self, i: &'a syn::ItemTrait) {
        self.add(&i.vis, &i.ident);
    }
    fn visit_item_type(&mut self, i: &'a syn::ItemType) {
        self.add(&i.vis, &i.ident);
    }
    fn visit_item_union(&mut self, i: &'a syn::ItemUnion) {
        self.add(&i.vis, &i.ident);
    }
}

#[test]
fn every_public_type_name_means_one_thing() {
    let mut v = PublicTypes::default();
    for (path, file) in sources() {
        v.file = path;
        v.visit_file(&file);
    }
    let twice: Vec<String> = v
        .names
        .iter()
        .filter(|(_, at)| at.len() > 1)
        .map(|(n, at)| format!("{n}: {}", at.join(", ")))
        .collect();
    assert!(twice.is_empty(), "public type names defined more than once:\n{}", twice.join("\n"));
}

/// The product's documents: the README, the book, the crates' own READMEs and docs.
fn documents() -> Vec<PathBuf> {
    let root = root();
    let mut out = vec![root.join("README.md")];
    out.extend(files(&root.join("docs"), ".md"));
    for c in CRATES {
        out.extend(
            files(&root.join(c), ".md")
                .into_iter()
                .filter(|p| !p.components().any(|c| c.as_os_str() == "target")),
        );
    }
    out
}

/// Lines that speak of the development process rather than the product.
fn process_words(text: &str) -> Vec<(usize, String)> {
    let lower = text.to_lowercase();
    let mut found = Vec::new();
    for (i, line) in lower.lines().enumerate() {
        let words: Vec<&str> =
            line.split(|c: char| !c.is_alphanumeric()).filter(|w| !w.is_empty()).collect();
        let pair =
            |a: &str, b: &dyn Fn(&str) -> bool| words.windows(2).any(|w| w[0] == a && b(w[1]));
        let numeric = |w: &str| w.chars().all(|c| c.is_ascii_digit());
        let ordinal = |w: &str| {
            let digits = w.trim_end_matches(|c: char| c.is_ascii_alphabetic());
            !digits.is_empty()
                && numeric(digits)
                && ["st", "nd", "rd", "th"].contains(&&w[digits.len()..])
        };
        let hit = pair("issue", &numeric)
            || pair("last", &|w| w == "session" || w == "stop")
            || words.windows(2).any(|w| ordinal(w[0]) && w[1] == "stop")
            || line.contains("design.md")
            || line.contains("style.md")
            || line.contains("../shared");
        if hit {
            found.push((i + 1, text.lines().nth(i).unwrap_or("").trim().to_string()));
        }
    }
    found
}

#[test]
fn the_product_speaks_of_the_product() {
    let root = root();
    let mut paths = documents();
    for c in CRATES {
        paths.extend(files(&root.join(c).join("src"), ".rs"));
    }
    // The files people read besides the code: scenarios and scripts.
    paths.extend(files(&root.join("scenarios"), ".toml"));
    paths.extend(files(&root.join("scripts"), ".sh"));
    let mut found = Vec::new();
    for p in paths {
        let text = fs::read_to_string(&p).unwrap_or_default();
        for (line, what) in process_words(&text) {
            found.push(format!("{}:{line}: {what}", p.strip_prefix(&root).unwrap().display()));
        }
    }
    assert!(
        found.is_empty(),
        "process words or references outside the repository:\n{}",
        found.join("\n")
    );
}

#[test]
fn the_process_word_rule_can_fail() {
    assert_eq!(process_words("fixed in issue 15").len(), 1);
    assert_eq!(process_words("as the last session measured").len(), 1);
    assert_eq!(process_words("the 7th stop").len(), 1);
    assert_eq!(process_words("see ../shared/DESIGN.md").len(), 1);
    assert!(process_words("the robot stops; a session of Zenoh; issues a command").is_empty());
}

#[test]
fn the_readme_is_short() {
    let text = fs::read_to_string(root().join("README.md")).unwrap();
    let n = text.lines().count();
    assert!(
        n <= MAX_README_LINES,
        "README.md has {n} lines (at most {MAX_README_LINES}); the rest belongs in docs/"
    );
}

#[test]
fn every_crates_readme_is_short() {
    let root = root();
    let long: Vec<String> = CRATES
        .iter()
        .map(|c| root.join(c).join("README.md"))
        .filter_map(|p| {
            let n = fs::read_to_string(&p).ok()?.lines().count();
            let name = p.strip_prefix(&root).unwrap().display().to_string();
            (n > MAX_CRATE_README_LINES).then(|| format!("{name}: {n} lines"))
        })
        .collect();
    assert!(
        long.is_empty(),
        "crate READMEs over {MAX_CRATE_README_LINES} lines (the rest belongs in docs/):\n{}",
        long.join("\n")
    );
}

/// Relative link targets of a Markdown text (`[text](target)`), without anchors.
fn links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find("](") {
        rest = &rest[i + 2..];
        let Some(end) = rest.find(')') else { break };
        let target = rest[..end].split_whitespace().next().unwrap_or("");
        let path = target.split('#').next().unwrap_or("");
        if !path.is_empty() && !path.contains("://") && !path.starts_with("mailto:") {
            out.push(path.to_string());
        }
    }
    out
}

#[test]
fn every_relative_link_of_the_documents_resolves() {
    let root = root();
    let docs = root.join("docs");
    assert!(
        docs.join("SUMMARY.md").is_file(),
        "docs/SUMMARY.md (the book's table of contents) is missing"
    );
    let mut broken = Vec::new();
    for p in documents() {
        let text = fs::read_to_string(&p).unwrap_or_default();
        for link in links(&text) {
            if !p.parent().unwrap().join(&link).exists() {
                broken.push(format!("{}: {link}", p.strip_prefix(&root).unwrap().display()));
            }
        }
    }
    assert!(broken.is_empty(), "links that resolve to nothing:\n{}", broken.join("\n"));
    let summary = fs::read_to_string(docs.join("SUMMARY.md")).unwrap();
    let listed = links(&summary);
    let unlisted: Vec<String> = files(&docs, ".md")
        .iter()
        .map(|p| p.strip_prefix(&docs).unwrap().display().to_string())
        .filter(|p| p != "SUMMARY.md" && !listed.contains(p))
        .collect();
    assert!(unlisted.is_empty(), "book pages missing from docs/SUMMARY.md: {unlisted:?}");
}

#[test]
fn the_link_reader_finds_relative_links_only() {
    let md = "see [a](docs/a.md#x), [b](https://x.org/b) and [c](../c.md \"title\")";
    assert_eq!(links(md), vec!["docs/a.md".to_string(), "../c.md".to_string()]);
}
