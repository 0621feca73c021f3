//! JUnit XML for CI servers (Jenkins, GitLab, GitHub test reporters): test suites of test
//! cases, each passed, failed (an expectation did not hold) or in error (could not run).
//!
//! The element and attribute names are those of the Ant JUnit schema that CI servers
//! read: `<testsuites>` of `<testsuite name tests failures errors skipped time>` of
//! `<testcase name classname time>` with an optional `<failure message type>` or
//! `<error message type>` whose text holds the details, and `<system-out>`.

use std::fmt::Write as _;

/// How a test case ended.
#[derive(Clone, Debug, PartialEq)]
pub enum Verdict {
    /// It passed.
    Pass,
    /// An expectation did not hold: a one-line message and details.
    Failure {
        /// One line.
        message: String,
        /// Details (every failed expectation, the run folder).
        details: String,
    },
    /// It could not run.
    Error {
        /// One line.
        message: String,
        /// Details.
        details: String,
    },
}

/// One test case.
#[derive(Clone, Debug, PartialEq)]
pub struct TestCase {
    /// Its name (`seed 7`, an expectation's text).
    pub name: String,
    /// Dotted class name CI servers group by (`sweep.rtk-outage-length.c2`).
    pub classname: String,
    /// Wall-clock seconds.
    pub time_s: f64,
    /// How it ended.
    pub verdict: Verdict,
    /// Extra output shown with the case (the run folder, values).
    pub system_out: Option<String>,
}

/// One test suite.
#[derive(Clone, Debug, PartialEq)]
pub struct TestSuite {
    /// Its name.
    pub name: String,
    /// Its cases.
    pub cases: Vec<TestCase>,
}

/// The XML document of `suites`.
pub fn to_xml(name: &str, suites: &[TestSuite]) -> String {
    let count =
        |s: &TestSuite, f: fn(&Verdict) -> bool| s.cases.iter().filter(|c| f(&c.verdict)).count();
    let failures = |v: &Verdict| matches!(v, Verdict::Failure { .. });
    let errors = |v: &Verdict| matches!(v, Verdict::Error { .. });
    let time = |s: &TestSuite| s.cases.iter().map(|c| c.time_s.max(0.0)).sum::<f64>();
    let mut x = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    let _ = writeln!(
        x,
        "<testsuites name=\"{}\" tests=\"{}\" failures=\"{}\" errors=\"{}\" time=\"{:.3}\">",
        esc(name),
        suites.iter().map(|s| s.cases.len()).sum::<usize>(),
        suites.iter().map(|s| count(s, failures)).sum::<usize>(),
        suites.iter().map(|s| count(s, errors)).sum::<usize>(),
        suites.iter().map(time).sum::<f64>()
    );
    for (id, s) in suites.iter().enumerate() {
        let _ = writeln!(
            x,
            "  <testsuite id=\"{id}\" name=\"{}\" tests=\"{}\" failures=\"{}\" errors=\"{}\" skipped=\"0\" time=\"{:.3}\">",
            esc(&s.name),
            s.cases.len(),
            count(s, failures),
            count(s, errors),
            time(s)
        );
        for c in &s.cases {
            let _ = write!(
                x,
                "    <testcase name=\"{}\" classname=\"{}\" time=\"{:.3}\"",
                esc(&c.name),
                esc(&c.classname),
                c.time_s.max(0.0)
            );
            if c.verdict == Verdict::Pass && c.system_out.is_none() {
                x.push_str("/>\n");
                continue;
            }
            x.push_str(">\n");
            match &c.verdict {
                Verdict::Pass => {}
                Verdict::Failure { message, details } => {
                    let _ = writeln!(
                        x,
                        "      <failure message=\"{}\" type=\"expectation\">{}</failure>",
                        esc(message),
                        esc(details)
                    );
                }
                Verdict::Error { message, details } => {
                    let _ = writeln!(
                        x,
                        "      <error message=\"{}\" type=\"error\">{}</error>",
                        esc(message),
                        esc(details)
                    );
                }
            }
            if let Some(out) = &c.system_out {
                let _ = writeln!(x, "      <system-out>{}</system-out>", esc(out));
            }
            x.push_str("    </testcase>\n");
        }
        x.push_str("  </testsuite>\n");
    }
    x.push_str("</testsuites>\n");
    x
}

/// XML text and attribute escaping; characters XML 1.0 cannot hold become U+FFFD.
fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            '\t' | '\n' | '\r' => out.push(c),
            c if (c as u32) < 0x20 || c == '\u{FFFE}' || c == '\u{FFFF}' => out.push('\u{FFFD}'),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_escapes_and_parses() {
        let suites = vec![TestSuite {
            name: "cell <0> & \"x\"".into(),
            cases: vec![
                TestCase {
                    name: "seed 1".into(),
                    classname: "sweep.a.c0".into(),
                    time_s: 1.5,
                    verdict: Verdict::Pass,
                    system_out: None,
                },
                TestCase {
                    name: "seed 2".into(),
                    classname: "sweep.a.c0".into(),
                    time_s: 2.0,
                    verdict: Verdict::Failure {
                        message: "ate_rmse_m.eif <= 0.1".into(),
                        details: "FAILS: a < b\u{1}".into(),
                    },
                    system_out: Some("runs/x".into()),
                },
                TestCase {
                    name: "seed 3".into(),
                    classname: "sweep.a.c0".into(),
                    time_s: 0.5,
                    verdict: Verdict::Error {
                        message: "no file".into(),
                        details: String::new(),
                    },
                    system_out: None,
                },
            ],
        }];
        let xml = to_xml("sweep a", &suites);
        let doc = roxmltree::Document::parse(&xml).unwrap();
        let root = doc.root_element();
        assert_eq!(root.tag_name().name(), "testsuites");
        assert_eq!(root.attribute("tests"), Some("3"));
        assert_eq!(root.attribute("failures"), Some("1"));
        assert_eq!(root.attribute("errors"), Some("1"));
        let suite = root.children().find(|n| n.is_element()).unwrap();
        assert_eq!(suite.attribute("name"), Some("cell <0> & \"x\""));
        assert_eq!(suite.attribute("time"), Some("4.000"));
        let failure = doc
            .descendants()
            .find(|n| n.has_tag_name("failure"))
            .unwrap();
        assert_eq!(failure.attribute("message"), Some("ate_rmse_m.eif <= 0.1"));
        assert_eq!(failure.text(), Some("FAILS: a < b\u{FFFD}"));
    }
}
