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
/// root) and its text without line comments.
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
            let text = std::fs::read_to_string(&path).expect("a source file");
            let code: Vec<&str> = text.lines().map(|line| line.split("//").next().unwrap_or("")).collect();
            modules.insert(name, code.join("\n"));
        }
    }
    modules
}

/// The module a path `crate::a::b::c` names: the longest prefix that is one (`lib` for an
/// item of the root).
fn resolve(modules: &BTreeMap<String, String>, segments: &[&str]) -> String {
    (1..=segments.len()).rev().map(|n| segments[..n].join("::")).find(|candidate| modules.contains_key(candidate)).unwrap_or_else(|| "lib".to_string())
}

/// The modules `text` names through `crate::` (groups `crate::{a, b::c}` too).
fn imports(modules: &BTreeMap<String, String>, text: &str) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    let ident = |c: char| c.is_ascii_alphanumeric() || c == '_';
    for (at, _) in text.match_indices("crate::") {
        let rest = &text[at + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            // The names at the group's top level, each a path of its own.
            let (mut depth, mut item) = (0, String::new());
            for c in group.chars() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        found.insert(resolve(modules, &item.split("::").map(str::trim).filter(|s| !s.is_empty() && s.chars().all(ident)).collect::<Vec<_>>()));
                        item.clear();
                        continue;
                    }
                    _ => {}
                }
                if depth == 0 && c != '{' {
                    item.push(c);
                }
            }
            let segments: Vec<&str> = item.split("::").map(str::trim).filter(|s| !s.is_empty() && s.chars().all(ident)).collect();
            if !segments.is_empty() {
                found.insert(resolve(modules, &segments));
            }
            continue;
        }
        let path: String = rest.chars().take_while(|&c| ident(c) || c == ':').collect();
        let segments: Vec<&str> = path.split("::").filter(|s| !s.is_empty()).collect();
        found.insert(resolve(modules, &segments));
    }
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

/// Each file's imports of other files (the root, `lib`, imports everything and is left out).
fn file_edges() -> BTreeMap<String, BTreeSet<String>> {
    let modules = shim_modules();
    modules
        .iter()
        .filter(|(name, _)| *name != "lib")
        .map(|(name, text)| {
            let mut to = imports(&modules, text);
            to.remove(name);
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
