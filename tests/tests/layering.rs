//! The layering of the workspace, checked on the sources: no module of any crate imports, directly
//! or through others, a module that imports it back; ivp-core's modules import only from the
//! layers below them (ARCHITECTURE.md, "Invariants"); and no two crates define public types of
//! the same name.
//!
//! A plain scan, no compiler: comments, strings and `#[cfg(test)]` items are removed, then every
//! `use` tree and every inline `crate::` / `super::` path is resolved to the module file it names
//! (following `pub use` re-exports to the module that defines the item). `pub use` of a module's
//! own children is structure, not a dependency.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// ivp-core's layers, lowest first. A module may import from a layer strictly below its own and
/// from its own top-level module; two modules of one layer never import each other.
const CORE_LAYERS: &[&[&str]] = &[&["geometry"], &["metrics", "prior"], &["infill", "nn"], &["inference"]];

/// Library crates scanned, as paths from the workspace root.
const CRATES: &[&str] = &["crates/ivp-core", "crates/ivp-data", "crates/ivp-train"];

type ModPath = Vec<String>;

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("tests/ sits in the workspace").to_path_buf()
}

// ---------------------------------------------------------------------------------------------
// Source cleaning
// ---------------------------------------------------------------------------------------------

/// The source with comments, string and character literals blanked out (lines kept).
fn strip_comments_and_literals(src: &str) -> String {
    let c: Vec<char> = src.chars().collect();
    let mut out = String::with_capacity(src.len());
    let mut i = 0;
    let keep_newlines = |s: &[char], out: &mut String| s.iter().filter(|&&ch| ch == '\n').for_each(|_| out.push('\n'));
    while i < c.len() {
        let rest = &c[i..];
        if rest.starts_with(&['/', '/']) {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if rest.starts_with(&['/', '*']) {
            let (start, mut depth) = (i, 0);
            while i < c.len() {
                if c[i..].starts_with(&['/', '*']) {
                    depth += 1;
                    i += 2;
                } else if c[i..].starts_with(&['*', '/']) {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
            keep_newlines(&c[start..i], &mut out);
        } else if c[i] == 'r'
            && (rest.starts_with(&['r', '"']) || rest.starts_with(&['r', '#']))
            && (i == 0 || !(c[i - 1].is_alphanumeric() || c[i - 1] == '_'))
        {
            // Raw string r#"..."#: find the closing quote followed by as many hashes.
            let start = i;
            i += 1;
            let mut hashes = 0;
            while i < c.len() && c[i] == '#' {
                hashes += 1;
                i += 1;
            }
            if i < c.len() && c[i] == '"' {
                i += 1;
                while i < c.len()
                    && !(c[i] == '"' && c[i + 1..].iter().take(hashes).filter(|&&h| h == '#').count() == hashes)
                {
                    i += 1;
                }
                i = (i + 1 + hashes).min(c.len());
                keep_newlines(&c[start..i], &mut out);
                out.push_str("\"\"");
            } else {
                out.extend(&c[start..i]);
            }
        } else if c[i] == '"' {
            let start = i;
            i += 1;
            while i < c.len() && c[i] != '"' {
                i += if c[i] == '\\' { 2 } else { 1 };
            }
            i += 1;
            keep_newlines(&c[start..i.min(c.len())], &mut out);
            out.push_str("\"\"");
        } else if c[i] == '\'' {
            // A character literal ('x', '\n', '\u{1F600}') or a lifetime ('a).
            if c.get(i + 1) == Some(&'\\') {
                i += 2;
                while i < c.len() && c[i] != '\'' {
                    i += 1;
                }
                i += 1;
                out.push_str("' '");
            } else if c.get(i + 2) == Some(&'\'') {
                i += 3;
                out.push_str("' '");
            } else {
                out.push('\'');
                i += 1;
            }
        } else {
            out.push(c[i]);
            i += 1;
        }
    }
    out
}

/// The index just past the item that starts at `from`: its `;`, or its `{ ... }` block.
fn item_end(src: &[u8], from: usize) -> usize {
    let mut i = from;
    let mut depth = 0usize;
    while i < src.len() {
        match src[i] {
            b'{' => depth += 1,
            b'}' => {
                depth -= 1;
                if depth == 0 {
                    return i + 1;
                }
            }
            b';' if depth == 0 => return i + 1,
            _ => {}
        }
        i += 1;
    }
    src.len()
}

/// `src` (already without comments and literals) without its `#[cfg(test)]` items, and the names
/// of the file modules it declares under `#[cfg(test)]` (`#[cfg(test)] mod tests;`).
fn strip_test_items(src: &str) -> (String, Vec<String>) {
    let mut out = src.to_string();
    let mut test_modules = Vec::new();
    while let Some(at) = out.find("#[cfg(test)]") {
        let bytes = out.as_bytes();
        let end = item_end(bytes, at);
        let item = &out[at..end];
        if let Some(name) = item.trim_end_matches(';').split_whitespace().skip_while(|w| *w != "mod").nth(1) {
            if item.trim_end().ends_with(';') {
                test_modules.push(name.to_string());
            }
        }
        let blank: String = item.chars().map(|ch| if ch == '\n' { '\n' } else { ' ' }).collect();
        out.replace_range(at..end, &blank);
    }
    (out, test_modules)
}

// ---------------------------------------------------------------------------------------------
// Use trees
// ---------------------------------------------------------------------------------------------

/// A `use` statement: its expanded paths (each with `self`/`*` and aliases dropped, plus the name
/// it binds) and whether it is `pub`.
struct UseDecl {
    public: bool,
    paths: Vec<(Vec<String>, String)>,
}

/// Expands `a::{b, c::{d as e, self}, f::*}` into `(path, bound name)` pairs.
fn expand_tree(tree: &str, prefix: &[String], out: &mut Vec<(Vec<String>, String)>) {
    let tree = tree.trim();
    if tree.is_empty() {
        return;
    }
    if let Some(open) = tree.find('{') {
        let head: Vec<String> =
            tree[..open].split("::").map(str::trim).filter(|s| !s.is_empty()).map(String::from).collect();
        let inner = &tree[open + 1..tree.rfind('}').expect("balanced use tree")];
        let mut full = prefix.to_vec();
        full.extend(head);
        let (mut depth, mut start) = (0, 0);
        for (i, ch) in inner.char_indices() {
            match ch {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    expand_tree(&inner[start..i], &full, out);
                    start = i + 1;
                }
                _ => {}
            }
        }
        expand_tree(&inner[start..], &full, out);
        return;
    }
    let (path, alias) = match tree.split_once(" as ") {
        Some((p, a)) => (p, Some(a.trim().to_string())),
        None => (tree, None),
    };
    let mut full = prefix.to_vec();
    full.extend(path.split("::").map(str::trim).filter(|s| !s.is_empty()).map(String::from));
    if full.last().is_some_and(|s| s == "self") {
        full.pop();
    }
    let name = alias.or_else(|| full.last().cloned()).unwrap_or_default();
    if full.last().is_some_and(|s| s == "*") {
        full.pop();
    }
    out.push((full, name));
}

/// Every `use` statement of `src`, and `src` with them blanked out.
fn use_declarations(src: &str) -> (Vec<UseDecl>, String) {
    let mut decls = Vec::new();
    let mut rest = src.to_string();
    let bytes = src.as_bytes();
    let is_word = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    let mut i = 0;
    while let Some(found) = src[i..].find("use ") {
        let at = i + found;
        i = at + 4;
        if at > 0 && is_word(bytes[at - 1]) {
            continue;
        }
        let Some(semi) = src[at..].find(';') else { break };
        let tree = &src[at + 4..at + semi];
        // `pub use`, `pub(crate) use`: look back over the visibility.
        let before = src[..at].trim_end();
        let public = before.ends_with("pub") || (before.ends_with(')') && before.contains("pub("));
        let mut paths = Vec::new();
        expand_tree(tree, &[], &mut paths);
        decls.push(UseDecl {
            public: public && !before.ends_with("pub(crate)") && !before.ends_with("pub(super)"),
            paths,
        });
        let blank: String = src[at..at + semi + 1].chars().map(|ch| if ch == '\n' { '\n' } else { ' ' }).collect();
        rest.replace_range(at..at + semi + 1, &blank);
        i = at + semi + 1;
    }
    (decls, rest)
}

/// Inline `crate::a::b` and `super::a` paths in code.
fn inline_paths(code: &str) -> Vec<Vec<String>> {
    let bytes = code.as_bytes();
    let mut paths = Vec::new();
    for anchor in ["crate::", "super::"] {
        let mut i = 0;
        while let Some(found) = code[i..].find(anchor) {
            let at = i + found;
            i = at + anchor.len();
            if at > 0 && (bytes[at - 1].is_ascii_alphanumeric() || bytes[at - 1] == b'_' || bytes[at - 1] == b':') {
                continue;
            }
            let end = code[at..]
                .find(|ch: char| !(ch.is_alphanumeric() || ch == '_' || ch == ':'))
                .map_or(code.len(), |e| at + e);
            paths.push(code[at..end].split("::").filter(|s| !s.is_empty()).map(String::from).collect());
        }
    }
    paths
}

// ---------------------------------------------------------------------------------------------
// Crates as module graphs
// ---------------------------------------------------------------------------------------------

struct Module {
    file: PathBuf,
    /// Non-test code, without `use` statements.
    code: String,
    uses: Vec<UseDecl>,
    /// `pub struct|enum|trait|type` names defined here.
    public_types: Vec<String>,
}

struct Crate {
    name: String,
    modules: BTreeMap<ModPath, Module>,
}

/// The module file of `name` declared in the file `parent_file` of module `parent`.
fn child_file(parent_file: &Path, parent: &ModPath, name: &str) -> Option<PathBuf> {
    let dir = parent_file.parent()?;
    let is_root = parent.is_empty() || parent_file.file_name().is_some_and(|f| f == "mod.rs");
    let base = if is_root { dir.to_path_buf() } else { dir.join(parent.last()?) };
    [base.join(format!("{name}.rs")), base.join(name).join("mod.rs")].into_iter().find(|p| p.is_file())
}

fn public_types(code: &str) -> Vec<String> {
    let words: Vec<&str> = code.split(|c: char| !(c.is_alphanumeric() || c == '_')).filter(|w| !w.is_empty()).collect();
    let mut names = Vec::new();
    for w in words.windows(3) {
        if w[0] == "pub" && ["struct", "enum", "trait", "type"].contains(&w[1]) {
            names.push(w[2].to_string());
        }
    }
    names
}

fn load_crate(dir: &Path) -> Crate {
    let name = dir.file_name().unwrap().to_string_lossy().into_owned();
    let mut modules = BTreeMap::new();
    let mut queue = vec![(Vec::<String>::new(), dir.join("src/lib.rs"))];
    while let Some((path, file)) = queue.pop() {
        let src = std::fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let (code, _test_modules) = strip_test_items(&strip_comments_and_literals(&src));
        let (uses, code) = use_declarations(&code);
        // File modules: `mod name;` (inline `mod name { ... }` blocks stay part of this file).
        let words: Vec<&str> = code.split(|c: char| c.is_whitespace()).filter(|w| !w.is_empty()).collect();
        for w in words.windows(2) {
            if w[0] == "mod" && w[1].ends_with(';') {
                let child = w[1].trim_end_matches(';');
                let file = child_file(&file, &path, child)
                    .unwrap_or_else(|| panic!("{}: no file for `mod {child};`", file.display()));
                let mut child_path = path.clone();
                child_path.push(child.to_string());
                queue.push((child_path, file));
            }
        }
        let public_types = public_types(&code);
        modules.insert(path, Module { file, code, uses, public_types });
    }
    Crate { name, modules }
}

impl Crate {
    /// The module a path used in module `from` names: the deepest module file along it, with
    /// re-exports followed to the module that defines the item. `None` for other crates.
    fn resolve(&self, from: &ModPath, path: &[String], hops: usize) -> Option<ModPath> {
        let (mut at, rest): (ModPath, &[String]) = match path.first().map(String::as_str) {
            Some("crate") => (Vec::new(), &path[1..]),
            Some("self") => (from.clone(), &path[1..]),
            Some("super") => {
                let mut at = from.clone();
                let mut rest = path;
                while rest.first().is_some_and(|s| s == "super") {
                    at.pop();
                    rest = &rest[1..];
                }
                (at, rest)
            }
            Some(first) => {
                let mut child = from.clone();
                child.push(first.to_string());
                if !self.modules.contains_key(&child) {
                    return None; // another crate, or std
                }
                (from.clone(), path)
            }
            None => return None,
        };
        for (i, segment) in rest.iter().enumerate() {
            let mut child = at.clone();
            child.push(segment.clone());
            if self.modules.contains_key(&child) {
                at = child;
                continue;
            }
            // An item of `at`: defined there, or re-exported from elsewhere.
            if hops < 8 {
                if let Some(target) = self.reexport(&at, segment, hops) {
                    return Some(target);
                }
            }
            let _ = i;
            break;
        }
        Some(at)
    }

    /// Where a `pub use` of module `at` that binds `name` leads.
    fn reexport(&self, at: &ModPath, name: &str, hops: usize) -> Option<ModPath> {
        let module = self.modules.get(at)?;
        module
            .uses
            .iter()
            .filter(|u| u.public)
            .flat_map(|u| &u.paths)
            .find(|(_, bound)| bound == name)
            .and_then(|(path, _)| self.resolve(at, path, hops + 1))
    }

    /// True when `path`, used in module `at`, starts at one of `at`'s own children (structure).
    fn is_child_path(&self, at: &ModPath, path: &[String]) -> bool {
        let first = match path.first().map(String::as_str) {
            Some("self") => path.get(1),
            Some("crate" | "super") | None => return false,
            Some(_) => path.first(),
        };
        first.is_some_and(|f| {
            let mut child = at.clone();
            child.push(f.clone());
            self.modules.contains_key(&child)
        })
    }

    /// Module -> the modules it imports from (itself excluded).
    fn edges(&self) -> BTreeMap<ModPath, BTreeSet<ModPath>> {
        let mut edges = BTreeMap::new();
        for (at, module) in &self.modules {
            let mut targets = BTreeSet::new();
            let used = module.uses.iter().flat_map(|u| u.paths.iter().map(move |(p, _)| (u.public, p.clone())));
            let inline = inline_paths(&module.code).into_iter().map(|p| (false, p));
            for (public, path) in used.chain(inline) {
                if public && self.is_child_path(at, &path) {
                    continue;
                }
                if let Some(target) = self.resolve(at, &path, 0) {
                    if &target != at {
                        targets.insert(target);
                    }
                }
            }
            edges.insert(at.clone(), targets);
        }
        edges
    }
}

fn show(path: &ModPath) -> String {
    if path.is_empty() {
        "crate".into()
    } else {
        path.join("::")
    }
}

/// A cycle of the graph, as the list of modules around it, if there is one.
fn find_cycle(edges: &BTreeMap<ModPath, BTreeSet<ModPath>>) -> Option<Vec<ModPath>> {
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        New,
        Open,
        Done,
    }
    fn visit(
        node: &ModPath,
        edges: &BTreeMap<ModPath, BTreeSet<ModPath>>,
        marks: &mut BTreeMap<ModPath, Mark>,
        stack: &mut Vec<ModPath>,
    ) -> Option<Vec<ModPath>> {
        marks.insert(node.clone(), Mark::Open);
        stack.push(node.clone());
        for next in edges.get(node).into_iter().flatten() {
            match marks.get(next).copied().unwrap_or(Mark::New) {
                Mark::Open => {
                    let start = stack.iter().position(|m| m == next).unwrap();
                    let mut cycle = stack[start..].to_vec();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                Mark::New => {
                    if let Some(cycle) = visit(next, edges, marks, stack) {
                        return Some(cycle);
                    }
                }
                Mark::Done => {}
            }
        }
        stack.pop();
        marks.insert(node.clone(), Mark::Done);
        None
    }
    let mut marks = BTreeMap::new();
    for node in edges.keys() {
        if marks.get(node).copied().unwrap_or(Mark::New) == Mark::New {
            if let Some(cycle) = visit(node, edges, &mut marks, &mut Vec::new()) {
                return Some(cycle);
            }
        }
    }
    None
}

fn crates() -> Vec<Crate> {
    CRATES.iter().map(|dir| load_crate(&workspace().join(dir))).collect()
}

#[test]
fn no_crate_has_a_module_cycle() {
    for krate in crates() {
        assert!(krate.modules.len() > 3, "{}: only {} modules found", krate.name, krate.modules.len());
        if let Some(cycle) = find_cycle(&krate.edges()) {
            let files: Vec<String> = cycle.iter().map(|m| krate.modules[m].file.display().to_string()).collect();
            panic!(
                "{}: modules import each other in a cycle: {}\n({})",
                krate.name,
                cycle.iter().map(show).collect::<Vec<_>>().join(" -> "),
                files.join(", ")
            );
        }
    }
}

#[test]
fn ivp_core_modules_import_only_from_lower_layers() {
    let core = crates().into_iter().find(|c| c.name == "ivp-core").unwrap();
    let layer_of = |top: &str| CORE_LAYERS.iter().position(|layer| layer.contains(&top));
    let mut violations = Vec::new();
    for (from, targets) in core.edges() {
        let Some(from_top) = from.first() else { continue }; // lib.rs only re-exports
        let from_layer = layer_of(from_top).unwrap_or_else(|| {
            panic!("ivp-core module `{from_top}` has no layer: add it to CORE_LAYERS and ARCHITECTURE.md")
        });
        for target in targets {
            let Some(to_top) = target.first() else {
                violations.push(format!("{} imports from the crate root; import from the module instead", show(&from)));
                continue;
            };
            if to_top == from_top {
                continue;
            }
            let to_layer = layer_of(to_top).expect("every top-level module has a layer");
            if to_layer >= from_layer {
                violations.push(format!(
                    "{} (layer {from_layer}) imports {} (layer {to_layer}) in {}",
                    show(&from),
                    show(&target),
                    core.modules[&from].file.display()
                ));
            }
        }
    }
    assert!(violations.is_empty(), "layering broken:\n{}", violations.join("\n"));
}

#[test]
fn no_two_crates_define_a_public_type_of_the_same_name() {
    let mut owners: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for krate in crates() {
        for module in krate.modules.values() {
            for name in &module.public_types {
                owners.entry(name.clone()).or_default().insert(format!("{} ({})", krate.name, module.file.display()));
            }
        }
    }
    let shared: Vec<String> = owners
        .iter()
        .filter(|(_, crates)| crates.iter().map(|c| c.split(' ').next().unwrap()).collect::<BTreeSet<_>>().len() > 1)
        .map(|(name, crates)| format!("{name}: {}", crates.iter().cloned().collect::<Vec<_>>().join(", ")))
        .collect();
    assert!(shared.is_empty(), "public types defined in more than one crate:\n{}", shared.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// The scanner's own tests: a scan that sees nothing would pass everything
// ---------------------------------------------------------------------------------------------

#[test]
fn the_scanner_sees_use_trees_inline_paths_and_skips_tests_and_comments() {
    let src = r#"
        //! use crate::doc::Nope;
        use crate::a::{b::{C, D as E}, f};
        pub use g::H;
        pub(crate) use super::i::J;
        fn k() { let s = "crate::string::Nope"; crate::m::n(); }
        #[cfg(test)]
        mod tests { use crate::test_only::X; }
        #[cfg(test)]
        mod fixtures;
    "#;
    let (code, test_modules) = strip_test_items(&strip_comments_and_literals(src));
    assert_eq!(test_modules, ["fixtures"]);
    let (uses, code) = use_declarations(&code);
    let paths: Vec<(bool, String)> =
        uses.iter().flat_map(|u| u.paths.iter().map(move |(p, _)| (u.public, p.join("::")))).collect();
    let want = [
        (false, "crate::a::b::C"),
        (false, "crate::a::b::D"),
        (false, "crate::a::f"),
        (true, "g::H"),
        (false, "super::i::J"),
    ];
    assert_eq!(paths, want.map(|(p, s)| (p, s.to_string())));
    assert_eq!(inline_paths(&code), [vec!["crate".to_string(), "m".into(), "n".into()]]);
}

#[test]
fn a_cycle_is_found_and_an_upward_import_is_seen() {
    let m = |s: &str| s.split("::").map(String::from).collect::<ModPath>();
    let mut edges = BTreeMap::new();
    edges.insert(m("a"), BTreeSet::from([m("b")]));
    edges.insert(m("b"), BTreeSet::from([m("c")]));
    edges.insert(m("c"), BTreeSet::from([m("a")]));
    assert_eq!(find_cycle(&edges).map(|c| c.len()), Some(4));
    edges.insert(m("c"), BTreeSet::new());
    assert_eq!(find_cycle(&edges), None);
    // The real tree: prior (layer 1) must depend on geometry (layer 0), and inference on nn.
    let core = crates().into_iter().find(|c| c.name == "ivp-core").unwrap();
    let edges = core.edges();
    assert!(edges[&m("prior")].iter().any(|t| t.first().is_some_and(|s| s == "geometry")));
    assert!(edges[&m("inference")].iter().any(|t| t.first().is_some_and(|s| s == "nn")));
}

/// Parents that use their children, not only declare and re-export them (ARCHITECTURE.md,
/// "Invariants"): `inference` composes its children into `ModelInfiller`; `nn::ops::conv2d` hands
/// the narrow layers to the kernels of its child `narrow`; ivp-data's `scene` composes shapes,
/// textures, layout and camera path into `Scene` and `render_clip`; ivp-train's `cli` parser names
/// each child's arguments and calls its `run_*`.
const PARENTS_THAT_COMPOSE: &[(&str, &str)] =
    &[("ivp-core", "inference"), ("ivp-core", "nn::ops::conv2d"), ("ivp-data", "scene"), ("ivp-train", "cli")];

#[test]
fn a_parent_module_only_declares_and_reexports_its_children() {
    let mut composing = Vec::new();
    for krate in crates() {
        for (at, targets) in krate.edges() {
            let allowed = PARENTS_THAT_COMPOSE.iter().any(|&(c, m)| c == krate.name && show(&at) == m);
            let mut children: Vec<String> =
                targets.iter().filter(|t| t.len() > at.len() && t.starts_with(&at)).map(show).collect();
            // Inline paths that start at a child (`data::WarpArgs`) are uses, and so is a name
            // re-exported from a child and then used in the parent's own code.
            let module = &krate.modules[&at];
            let child_names = krate.modules.keys().filter(|m| m.len() == at.len() + 1 && m.starts_with(&at));
            for child in child_names.map(|m| m.last().unwrap()) {
                let pattern = format!("{child}::");
                let bytes = module.code.as_bytes();
                let used = module.code.match_indices(&pattern).any(|(i, _)| {
                    i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_' || bytes[i - 1] == b':')
                });
                if used {
                    children.push(format!("{child}:: (inline path)"));
                }
            }
            let words: BTreeSet<&str> =
                module.code.split(|c: char| !(c.is_alphanumeric() || c == '_')).filter(|w| !w.is_empty()).collect();
            for u in module.uses.iter().filter(|u| u.public) {
                for (path, bound) in &u.paths {
                    // (`mod conv2d;` beside `pub use conv2d::conv2d;` names the module, not the item.)
                    let is_module_name = krate.is_child_path(&at, std::slice::from_ref(bound));
                    if krate.is_child_path(&at, path) && !is_module_name && words.contains(bound.as_str()) {
                        children.push(format!("{} (re-exported, then used)", path.join("::")));
                    }
                }
            }
            if !children.is_empty() {
                composing.push((krate.name.clone(), show(&at)));
            }
            assert!(
                allowed || children.is_empty(),
                "{}: module `{}` uses its own children {children:?}: move what it needs below them, or list it in \
                 PARENTS_THAT_COMPOSE and ARCHITECTURE.md",
                krate.name,
                show(&at)
            );
        }
    }
    // The children of a composing parent do not import from it: that would be a cycle.
    for krate in crates() {
        let edges = krate.edges();
        for (at, targets) in &edges {
            let parent = &at[..at.len().saturating_sub(1)];
            let composing = PARENTS_THAT_COMPOSE.iter().any(|&(c, m)| c == krate.name && show(&parent.to_vec()) == m);
            if !at.is_empty() && composing {
                assert!(!targets.contains(&parent.to_vec()), "{}: `{}` imports its parent", krate.name, show(at));
            }
        }
    }
    // The listed parents do use their children: the check sees such uses, and the list is not stale.
    for &(c, m) in PARENTS_THAT_COMPOSE {
        assert!(composing.contains(&(c.to_string(), m.to_string())), "{c}: `{m}` no longer uses its children");
    }
}
