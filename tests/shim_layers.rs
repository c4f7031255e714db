//! The shim's files import only downwards: no file, and no folder taken whole (`schedule/`,
//! `signals/`, `abi/`), reaches itself again through the `crate::` paths it names; and the
//! schedule (a followed thread's side of climbsim's scheduler, `shim/src/schedule/`) sits below
//! every followed call, importing only the layers under it. Read from the sources, as
//! docs/architecture.md describes them; a new import that breaks a layer fails here, naming it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// What the schedule may import besides itself: the block's layout and the system-call layer.
const UNDER_THE_SCHEDULE: [&str; 5] = ["abi", "sys", "native", "handlers", "marker"];

/// Every source file of the shim: its module path (`schedule::park`; `lib` for the crate's
/// root) and its code without comments and string literals.
fn shim_modules() -> BTreeMap<String, String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("shim/src");
    let mut modules = BTreeMap::new();
    let mut folders = vec![root.clone()];
    while let Some(folder) = folders.pop() {
        for entry in std::fs::read_dir(&folder).expect("a folder of shim/src") {
            let path = entry.expect("an entry").path();
            if path.is_dir() {
                folders.push(path);
                continue;
            }
            if path.extension().is_none_or(|ext| ext != "rs") {
                continue;
            }
            let relative = path.strip_prefix(&root).expect("under shim/src").with_extension("");
            let mut parts: Vec<String> = relative.iter().map(|part| part.to_string_lossy().into_owned()).collect();
            if parts.last().is_some_and(|last| last == "mod") {
                parts.pop();
            }
            let name = if parts == ["lib"] { "lib".to_string() } else { parts.join("::") };
            modules.insert(name, code_only(&std::fs::read_to_string(&path).expect("a source file")));
        }
    }
    modules
}

/// `text` without its comments (line and block) and the insides of its string literals (raw
/// ones too), which name no module.
fn code_only(text: &str) -> String {
    let chars: Vec<char> = text.chars().collect();
    let mut code = String::with_capacity(text.len());
    let mut at = 0;
    while at < chars.len() {
        let rest = &chars[at..];
        if rest.starts_with(&['/', '/']) {
            while at < chars.len() && chars[at] != '\n' {
                at += 1;
            }
        } else if rest.starts_with(&['/', '*']) {
            let mut depth = 0;
            while at < chars.len() {
                if chars[at..].starts_with(&['/', '*']) {
                    depth += 1;
                    at += 2;
                } else if chars[at..].starts_with(&['*', '/']) {
                    depth -= 1;
                    at += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    at += 1;
                }
            }
        } else if rest[0] == 'r' && rest.get(1).is_some_and(|&c| c == '"' || c == '#') && (at == 0 || !ident(chars[at - 1])) {
            // r"...", r#"..."#: to the quote followed by as many hashes.
            let hashes = rest[1..].iter().take_while(|&&c| c == '#').count();
            at += 2 + hashes;
            while at < chars.len() && !(chars[at] == '"' && chars[at + 1..].iter().take(hashes).filter(|&&c| c == '#').count() == hashes) {
                at += 1;
            }
            at += 1 + hashes;
            code.push_str("\"\"");
        } else if rest[0] == '"' {
            at += 1;
            while at < chars.len() && chars[at] != '"' {
                at += if chars[at] == '\\' { 2 } else { 1 };
            }
            at += 1;
            code.push_str("\"\"");
        } else {
            code.push(rest[0]);
            at += 1;
        }
    }
    code
}

fn ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// The module a path (`a::b::c`, from the crate's root) names: the longest prefix that is one
/// (`lib` for an item of the root).
fn resolve(modules: &BTreeMap<String, String>, segments: &[String]) -> String {
    (1..=segments.len()).rev().map(|n| segments[..n].join("::")).find(|candidate| modules.contains_key(candidate)).unwrap_or_else(|| "lib".to_string())
}

/// The paths a use tree at the start of `text` names, each from `prefix` on (`a::b`,
/// `a::{b, c::{d, e}}`, `a::*`): whole paths, groups expanded.
fn use_tree(text: &str, prefix: &[String]) -> Vec<Vec<String>> {
    let mut path = prefix.to_vec();
    let mut rest = text.trim_start();
    loop {
        let name: String = rest.chars().take_while(|&c| ident(c)).collect();
        if name.is_empty() {
            break;
        }
        path.push(name.clone());
        rest = rest[name.len()..].trim_start();
        match rest.strip_prefix("::") {
            Some(after) => rest = after.trim_start(),
            None => return vec![path],
        }
    }
    let Some(group) = rest.strip_prefix('{') else { return vec![path] };
    // The group's items at its top level, each a tree of its own.
    let (mut depth, mut item_start, mut paths) = (0, 0, Vec::new());
    for (index, c) in group.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => {
                paths.extend(use_tree(&group[item_start..index], &path));
                return paths;
            }
            '}' => depth -= 1,
            ',' if depth == 0 => {
                paths.extend(use_tree(&group[item_start..index], &path));
                item_start = index + 1;
            }
            _ => {}
        }
    }
    paths
}

/// The modules `module`'s code names: through `crate::` and `super::` (groups too), and a
/// folder's own files by their names (`timers::x` in `signals/mod.rs`).
fn imports(modules: &BTreeMap<String, String>, module: &str, text: &str) -> BTreeSet<String> {
    let own: Vec<String> = if module == "lib" { Vec::new() } else { module.split("::").map(str::to_string).collect() };
    let children: Vec<String> = modules.keys().filter_map(|m| m.strip_prefix(&format!("{module}::")).filter(|child| !child.contains("::")).map(str::to_string)).collect();
    let mut found = BTreeSet::new();
    let chars: Vec<(usize, char)> = text.char_indices().collect();
    for (position, &(at, _)) in chars.iter().enumerate() {
        let before = position.checked_sub(1).map(|p| chars[p].1);
        if before.is_some_and(|c| ident(c) || c == ':') {
            continue;
        }
        let rest = &text[at..];
        let (base, after) = if let Some(after) = rest.strip_prefix("crate::") {
            (Vec::new(), after)
        } else if rest.starts_with("super::") {
            // Each `super::` one level up from this module.
            let mut base = own.clone();
            let mut after = rest;
            while let Some(next) = after.strip_prefix("super::") {
                base.pop();
                after = next;
            }
            (base, after)
        } else if children.iter().any(|child| rest.starts_with(&format!("{child}::"))) {
            (own.clone(), rest)
        } else {
            continue;
        };
        for path in use_tree(after, &base) {
            found.insert(resolve(modules, &path));
        }
    }
    found.remove(module);
    found
}

/// A loop in `edges`, if there is one: the modules on it, in order.
fn find_loop(edges: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(node: &str, edges: &BTreeMap<String, BTreeSet<String>>, done: &mut BTreeSet<String>, path: &mut Vec<String>) -> Option<Vec<String>> {
        if let Some(at) = path.iter().position(|on| on == node) {
            let mut cycle = path[at..].to_vec();
            cycle.push(node.to_string());
            return Some(cycle);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_string());
        for next in edges.get(node).into_iter().flatten() {
            if let Some(cycle) = visit(next, edges, done, path) {
                return Some(cycle);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    edges.keys().find_map(|node| visit(node, edges, &mut done, &mut Vec::new()))
}

/// Each file's imports of other files (the root, `lib`, imports everything and is left out; a
/// folder's `mod.rs` may use its own files).
fn file_edges() -> BTreeMap<String, BTreeSet<String>> {
    let modules = shim_modules();
    modules
        .iter()
        .filter(|(name, _)| *name != "lib")
        .map(|(name, text)| {
            // A folder's `mod.rs` is its face: what it takes from its own files is no arrow.
            let to = imports(&modules, name, text).into_iter().filter(|to| !to.starts_with(&format!("{name}::"))).collect();
            (name.clone(), to)
        })
        .collect()
}

/// The folder (or top-level file) a module is in: `schedule::park` → `schedule`.
fn unit(module: &str) -> String {
    module.split("::").next().unwrap_or(module).to_string()
}

#[test]
fn no_file_of_the_shim_reaches_itself_through_its_imports() {
    let edges = file_edges();
    assert!(edges.len() > 30, "read the shim's files ({} found)", edges.len());
    assert!(edges["wait"].contains("schedule::park"), "the reader sees wait.rs import schedule/park.rs: {:?}", edges["wait"]);
    assert_eq!(find_loop(&edges), None, "a circle of imports among the shim's files");
}

#[test]
fn no_folder_of_the_shim_taken_whole_reaches_itself_through_its_imports() {
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (from, to) in file_edges() {
        let from = unit(&from);
        let to: BTreeSet<String> = to.iter().map(|m| unit(m)).filter(|m| *m != from && m != "lib").collect();
        edges.entry(from).or_default().extend(to);
    }
    assert!(edges.contains_key("schedule") && edges.contains_key("signals"), "the folders are read: {:?}", edges.keys());
    assert_eq!(find_loop(&edges), None, "a circle of imports among the shim's folders (each taken whole)");
}

#[test]
fn the_schedule_imports_only_what_is_under_it() {
    let mut above = BTreeSet::new();
    for (from, to) in file_edges().iter().filter(|(from, _)| unit(from) == "schedule") {
        for module in to.iter().filter(|m| unit(m) != "schedule" && !UNDER_THE_SCHEDULE.contains(&unit(m).as_str())) {
            above.insert(format!("{from} imports {module}"));
        }
    }
    assert!(above.is_empty(), "shim/src/schedule/ must stay below every followed call: {above:?}");
}
