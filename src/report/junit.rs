//! JUnit XML for `climbsim check`: one test case per scenario, failed when one of its `[expect]`
//! thresholds was not met, so CI systems show regressions like failing tests.

use std::fmt::Write as _;
use std::path::Path;

use super::ReportError;
use super::atomic::write_bytes_atomically;

/// The outcome of one scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct JunitCase {
    /// The scenario's name (its file stem, say).
    pub name: String,
    /// How long checking it took, in seconds.
    pub time_s: f64,
    /// One message per unmet expectation, e.g. `distance.overshoot_pct = 12.3 > 10`; empty if
    /// the scenario passed.
    pub failure_messages: Vec<String>,
    /// What the case printed (an external controller's log), as `<system-out>`.
    pub system_out: Option<String>,
    /// The scenario could not be loaded or run (a controller that cannot start, a broken
    /// file): an `<error>`, counted in `errors`, not a `<failure>` of the thing under test.
    pub broken: bool,
}

/// The JUnit XML document for one suite of cases:
///
/// ```xml
/// <testsuites name=".." tests="N" failures="F" errors="0" time="..">
///   <testsuite name=".." tests="N" failures="F" errors="0" skipped="0" time="..">
///     <testcase name=".." classname=".." time="..">
///       <failure message="first; second" type="expectation">first
/// second</failure>
///     </testcase>
///   </testsuite>
/// </testsuites>
/// ```
///
/// A failed case has one `<failure>` (several are not valid JUnit for every consumer), a broken
/// one an `<error>` instead: its `message` joins the messages with `; `, its text lists them one
/// per line. `failures` counts failed cases, `errors` broken ones. Times are in seconds with millisecond resolution; a non-finite time is written
/// as 0.
pub fn junit_xml(suite_name: &str, cases: &[JunitCase]) -> String {
    let broken = cases.iter().filter(|case| case.broken).count();
    let failed = cases.iter().filter(|case| !case.broken && !case.failure_messages.is_empty()).count();
    let total_time: f64 = cases.iter().map(|case| seconds(case.time_s)).sum();
    let suite = escape_attribute(suite_name);
    let counts = format!(r#"tests="{}" failures="{failed}" errors="{broken}""#, cases.len());
    let mut xml = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    // Writing into a String cannot fail, hence the ignored fmt::Results.
    let _ = writeln!(xml, r#"<testsuites name="{suite}" {counts} time="{total_time:.3}">"#);
    let _ = writeln!(xml, r#"  <testsuite name="{suite}" {counts} skipped="0" time="{total_time:.3}">"#);
    for case in cases {
        let opening = format!(r#"    <testcase name="{}" classname="{suite}" time="{:.3}""#, escape_attribute(&case.name), seconds(case.time_s));
        if case.failure_messages.is_empty() && case.system_out.is_none() {
            let _ = writeln!(xml, "{opening}/>");
            continue;
        }
        let _ = writeln!(xml, "{opening}>");
        if !case.failure_messages.is_empty() {
            let (element, kind) = if case.broken { ("error", "error") } else { ("failure", "expectation") };
            let _ = writeln!(xml, r#"      <{element} message="{}" type="{kind}">{}</{element}>"#, escape_attribute(&case.failure_messages.join("; ")), escape_text(&case.failure_messages.join("\n")));
        }
        if let Some(out) = &case.system_out {
            let _ = writeln!(xml, "      <system-out>{}</system-out>", escape_text(out));
        }
        let _ = writeln!(xml, "    </testcase>");
    }
    xml.push_str("  </testsuite>\n</testsuites>\n");
    xml
}

/// Writes [`junit_xml`] to `path` atomically.
pub fn write_junit(path: &Path, suite_name: &str, cases: &[JunitCase]) -> Result<(), ReportError> {
    write_bytes_atomically(path, junit_xml(suite_name, cases).as_bytes())
}

fn seconds(time_s: f64) -> f64 {
    if time_s.is_finite() { time_s } else { 0.0 }
}

/// Escapes text content: markup characters become entities and characters XML 1.0 forbids
/// (most control characters) become U+FFFD, so any message gives a well-formed document.
fn escape_text(text: &str) -> String {
    escape(text, false)
}

/// Escapes an attribute value, which is double-quoted; line breaks and tabs are written as
/// character references because parsers would otherwise normalise them to spaces.
fn escape_attribute(text: &str) -> String {
    escape(text, true)
}

fn escape(text: &str, attribute: bool) -> String {
    let mut escaped = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => escaped.push_str("&amp;"),
            '<' => escaped.push_str("&lt;"),
            '>' => escaped.push_str("&gt;"),
            '"' if attribute => escaped.push_str("&quot;"),
            '\'' if attribute => escaped.push_str("&apos;"),
            '\n' if attribute => escaped.push_str("&#10;"),
            '\r' => escaped.push_str("&#13;"),
            '\t' if attribute => escaped.push_str("&#9;"),
            '\t' | '\n' => escaped.push(c),
            c if c < ' ' || c == '\u{FFFE}' || c == '\u{FFFF}' => escaped.push('\u{FFFD}'),
            c => escaped.push(c),
        }
    }
    escaped
}

#[cfg(test)]
mod tests {
    use super::*;
    use quick_xml::Reader;
    use quick_xml::events::Event;

    fn case(name: &str, failures: &[&str]) -> JunitCase {
        JunitCase { name: name.to_owned(), time_s: 1.25, failure_messages: failures.iter().map(|&message| message.to_owned()).collect(), system_out: None, broken: false }
    }

    /// Every element with its attributes (unescaped), parsed by a real XML parser.
    fn parse(xml: &str) -> Vec<(String, Vec<(String, String)>)> {
        let mut reader = Reader::from_str(xml);
        let mut elements = Vec::new();
        loop {
            match reader.read_event().expect("well-formed XML") {
                Event::Start(element) | Event::Empty(element) => {
                    let attributes = element
                        .attributes()
                        .map(|attribute| {
                            let attribute = attribute.expect("a well-formed attribute");
                            let key = String::from_utf8(attribute.key.as_ref().to_vec()).expect("UTF-8");
                            let value = attribute.decode_and_unescape_value(reader.decoder()).expect("valid escapes").into_owned();
                            (key, value)
                        })
                        .collect();
                    let name = String::from_utf8(element.name().as_ref().to_vec()).expect("UTF-8");
                    elements.push((name, attributes));
                }
                Event::Eof => break,
                _ => {}
            }
        }
        elements
    }

    fn attribute<'a>(element: &'a (String, Vec<(String, String)>), key: &str) -> &'a str {
        element.1.iter().find(|(name, _)| name == key).map(|(_, value)| value.as_str()).unwrap_or("")
    }

    #[test]
    fn counts_cases_and_failed_cases() {
        let cases = [case("flat", &[]), case("bumpy", &["overshoot 12 % > 10 %", "rise time 3 s > 2 s"]), case("wall", &["never settled"])];
        let xml = junit_xml("climbsim check", &cases);
        let elements = parse(&xml);
        let names: Vec<&str> = elements.iter().map(|(name, _)| name.as_str()).collect();
        assert_eq!(names, ["testsuites", "testsuite", "testcase", "testcase", "failure", "testcase", "failure"]);
        for suite in &elements[..2] {
            assert_eq!(attribute(suite, "tests"), "3");
            assert_eq!(attribute(suite, "failures"), "2");
            assert_eq!(attribute(suite, "time"), "3.750");
        }
        assert_eq!(attribute(&elements[2], "name"), "flat");
        assert_eq!(attribute(&elements[2], "time"), "1.250");
        assert_eq!(attribute(&elements[4], "message"), "overshoot 12 % > 10 %; rise time 3 s > 2 s");
    }

    #[test]
    fn names_and_messages_are_escaped() {
        let nasty = "a<b & \"c\" 'd'\nline\u{1}";
        let xml = junit_xml("suite & co", &[case(nasty, &[nasty])]);
        let elements = parse(&xml);
        assert_eq!(attribute(&elements[0], "name"), "suite & co");
        assert_eq!(attribute(&elements[2], "name"), "a<b & \"c\" 'd'\nline\u{FFFD}");
        assert_eq!(attribute(&elements[3], "message"), "a<b & \"c\" 'd'\nline\u{FFFD}");
        assert!(xml.contains(">a&lt;b &amp; \"c\" 'd'\nline\u{FFFD}</failure>"), "{xml}");
    }

    #[test]
    fn a_controllers_output_is_the_cases_system_out() {
        let mut failed = case("external", &["controller ended before the scenario did"]);
        failed.system_out = Some("Traceback <stdin>\nKeyError: & 'x'".to_owned());
        let mut passed = case("external-ok", &[]);
        passed.system_out = Some("line_follower: 500 control periods".to_owned());
        let xml = junit_xml("climbsim check", &[failed, passed]);
        let names: Vec<String> = parse(&xml).into_iter().map(|(name, _)| name).collect();
        assert_eq!(names.iter().filter(|n| *n == "system-out").count(), 2, "{xml}");
        assert_eq!(names.iter().filter(|n| *n == "failure").count(), 1, "{xml}");
        assert!(xml.contains("Traceback &lt;stdin&gt;\nKeyError: &amp; 'x'"), "{xml}");
    }

    #[test]
    fn a_case_that_could_not_run_is_an_error_not_a_failure() {
        let mut broken = case("missing-controller", &["cannot start the controller `./nope`"]);
        broken.broken = true;
        let xml = junit_xml("climbsim check", &[broken, case("wall", &["never settled"])]);
        let elements = parse(&xml);
        let names: Vec<&str> = elements.iter().map(|(name, _)| name.as_str()).collect();
        assert_eq!(names, ["testsuites", "testsuite", "testcase", "error", "testcase", "failure"]);
        for suite in &elements[..2] {
            assert_eq!((attribute(suite, "failures"), attribute(suite, "errors")), ("1", "1"), "{xml}");
        }
        assert_eq!(attribute(&elements[3], "message"), "cannot start the controller `./nope`");
    }

    #[test]
    fn an_empty_suite_is_valid() {
        let xml = junit_xml("none", &[]);
        let elements = parse(&xml);
        assert_eq!(elements.len(), 2);
        assert_eq!(attribute(&elements[1], "tests"), "0");
    }

    #[test]
    fn the_file_is_written() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("junit.xml");
        write_junit(&path, "climbsim check", &[case("flat", &[])]).expect("written");
        let xml = std::fs::read_to_string(&path).expect("readable");
        assert_eq!(parse(&xml).len(), 3);
    }
}
