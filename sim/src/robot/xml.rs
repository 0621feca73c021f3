//! The XML-level checks of a URDF, before `urdf-rs` reads it: size limits, the root
//! element, nesting depth, link and joint counts, and every attribute vinebench reads as
//! a number, each error located (line and column) and naming its link or joint.
//!
//! `urdf-rs` reports a bad number without saying where it is (and ignores words among the
//! numbers of a vector), and builds a recursive tree that a deeply nested file would
//! overflow the stack with; these checks run on `roxmltree`'s flat document first.

use super::{
    MAX_URDF_BYTES, MAX_URDF_DEPTH, MAX_URDF_JOINTS, MAX_URDF_LINKS, MAX_URDF_NODES, RobotError,
};
use roxmltree::{Document, Node, ParsingOptions};
use std::collections::BTreeMap;

/// Where elements are in the file: `<link name="x">`, `<joint name="x">`,
/// `<gazebo reference="x">`, `<transmission name="x">`, `<plugin name="x">` → byte
/// offset of their first occurrence (turned into a line and column only for an error:
/// that costs a pass over the text).
pub(super) type Positions = BTreeMap<String, usize>;

/// A numeric attribute vinebench reads: element, attribute, how many numbers, whether
/// the element needs it, and the unit or meaning (for the message).
struct NumericAttr {
    element: &'static str,
    attribute: &'static str,
    count: usize,
    required: bool,
    /// Infinite values allowed (limits: "no limit").
    infinite_ok: bool,
    meaning: &'static str,
}

const fn attr(
    element: &'static str,
    attribute: &'static str,
    count: usize,
    required: bool,
    meaning: &'static str,
) -> NumericAttr {
    NumericAttr {
        element,
        attribute,
        count,
        required,
        infinite_ok: false,
        meaning,
    }
}

const fn limit(attribute: &'static str, meaning: &'static str) -> NumericAttr {
    NumericAttr {
        element: "limit",
        attribute,
        count: 1,
        required: false,
        infinite_ok: true,
        meaning,
    }
}

/// The numeric attributes of `<link>`, `<joint>` and `<material>` elements.
const NUMERIC: &[NumericAttr] = &[
    attr("origin", "xyz", 3, false, "a position, m"),
    attr("origin", "rpy", 3, false, "roll, pitch and yaw, rad"),
    attr("mass", "value", 1, true, "the link's mass, kg"),
    attr("inertia", "ixx", 1, true, "a moment of inertia, kg·m²"),
    attr("inertia", "ixy", 1, true, "a product of inertia, kg·m²"),
    attr("inertia", "ixz", 1, true, "a product of inertia, kg·m²"),
    attr("inertia", "iyy", 1, true, "a moment of inertia, kg·m²"),
    attr("inertia", "iyz", 1, true, "a product of inertia, kg·m²"),
    attr("inertia", "izz", 1, true, "a moment of inertia, kg·m²"),
    attr("box", "size", 3, true, "the box's sizes, m"),
    attr("cylinder", "radius", 1, true, "the radius, m"),
    attr("cylinder", "length", 1, true, "the length, m"),
    attr("capsule", "radius", 1, true, "the radius, m"),
    attr("capsule", "length", 1, true, "the length, m"),
    attr("sphere", "radius", 1, true, "the radius, m"),
    attr("mesh", "scale", 3, false, "scale factors"),
    attr(
        "color",
        "rgba",
        4,
        true,
        "red, green, blue and alpha in [0, 1]",
    ),
    attr("axis", "xyz", 3, true, "the joint axis"),
    limit("lower", "the lower position limit"),
    limit("upper", "the upper position limit"),
    limit("effort", "the effort limit, N·m or N"),
    limit("velocity", "the speed limit, rad/s or m/s"),
    limit("acceleration", "the acceleration limit"),
    limit("deceleration", "the deceleration limit"),
    limit("jerk", "the jerk limit"),
    attr("dynamics", "damping", 1, false, "viscous damping"),
    attr("dynamics", "friction", 1, false, "Coulomb friction"),
    attr("mimic", "multiplier", 1, false, "a factor"),
    attr("mimic", "offset", 1, false, "an offset"),
    attr("calibration", "rising", 1, false, "a position"),
    attr("calibration", "falling", 1, false, "a position"),
    attr(
        "safety_controller",
        "soft_lower_limit",
        1,
        false,
        "a position",
    ),
    attr(
        "safety_controller",
        "soft_upper_limit",
        1,
        false,
        "a position",
    ),
    attr("safety_controller", "k_position", 1, false, "a gain"),
    attr("safety_controller", "k_velocity", 1, false, "a gain"),
];

/// Joint types URDF defines.
const JOINT_TYPES: &[&str] = &[
    "revolute",
    "continuous",
    "prismatic",
    "fixed",
    "floating",
    "planar",
    "spherical",
];

/// Geometry elements URDF defines.
const SHAPES: &[&str] = &["box", "cylinder", "sphere", "capsule", "mesh"];

/// A [`RobotError::Located`] at byte offset `at` of `doc`'s text.
pub(super) fn located(
    doc: &Document,
    source: &str,
    at: usize,
    element: impl Into<String>,
    problem: impl Into<String>,
) -> RobotError {
    let pos = doc.text_pos_at(at);
    RobotError::Located {
        file: source.to_string(),
        line: pos.row,
        column: pos.col,
        element: element.into(),
        problem: problem.into(),
    }
}

/// Parses the XML of a URDF (at most [`MAX_URDF_BYTES`] and [`MAX_URDF_NODES`]); a
/// syntax error says where, and a file that ends too early says so.
pub(super) fn document<'a>(text: &'a str, source: &str) -> Result<Document<'a>, RobotError> {
    let parse_error = |message: String| RobotError::Parse {
        file: source.to_string(),
        message,
    };
    if text.len() > MAX_URDF_BYTES {
        return Err(parse_error(format!(
            "{} bytes, more than the {MAX_URDF_BYTES} bytes a URDF may have (MAX_URDF_BYTES)",
            text.len()
        )));
    }
    let options = ParsingOptions {
        allow_dtd: false,
        nodes_limit: MAX_URDF_NODES,
        ..ParsingOptions::default()
    };
    Document::parse_with_options(text, options).map_err(|e| match e {
        roxmltree::Error::UnexpectedEndOfStream | roxmltree::Error::UnclosedRootNode => {
            let line = text.lines().count().max(1);
            let open = last_open_tag(text);
            parse_error(format!(
                "the XML ends at line {line} (the end of the file) before {}{}: is the file \
                 truncated? ({e})",
                match open {
                    Some(tag) => format!("`<{tag}` is complete"),
                    None => "its elements are closed".to_string(),
                },
                open_owner(text)
            ))
        }
        roxmltree::Error::NodesLimitReached => parse_error(format!(
            "more than {MAX_URDF_NODES} XML nodes (MAX_URDF_NODES)"
        )),
        other => {
            let pos = other.pos();
            let at = offset_of(text, pos.row, pos.col);
            if !text[at..].contains('>') {
                // The bad token runs to the end of the file.
                parse_error(format!(
                    "the XML ends at line {} (the end of the file) inside a tag that began at \
                     {}:{}: is the file truncated? ({other})",
                    text.lines().count().max(1),
                    pos.row,
                    pos.col
                ))
            } else {
                parse_error(format!("XML syntax error: {other}"))
            }
        }
    })
}

/// Byte offset of 1-based `(row, col)` (columns count characters) in `text`, clamped to
/// its length.
fn offset_of(text: &str, row: u32, col: u32) -> usize {
    let mut line_start = 0;
    for _ in 1..row {
        match text[line_start..].find('\n') {
            Some(i) => line_start += i + 1,
            None => return text.len(),
        }
    }
    text[line_start..]
        .char_indices()
        .nth(col.saturating_sub(1) as usize)
        .map_or(text.len(), |(i, _)| line_start + i)
}

/// ` inside <link name="x"> (line n)` when `text` ends inside a `<link>` or `<joint>`
/// element, else empty (for a truncated file's message).
fn open_owner(text: &str) -> String {
    let start = match (text.rfind("<link"), text.rfind("<joint")) {
        (Some(a), Some(b)) => a.max(b),
        (Some(a), None) | (None, Some(a)) => a,
        (None, None) => return String::new(),
    };
    let rest = &text[start..];
    let tag_end = rest.find('>');
    let closed = rest.contains("</link") || rest.contains("</joint");
    let self_closed = tag_end.is_some_and(|i| rest[..i].ends_with('/'));
    if closed || self_closed {
        return String::new();
    }
    let tag = if rest.starts_with("<link") {
        "link"
    } else {
        "joint"
    };
    let name = rest
        .find("name=")
        .filter(|&i| tag_end.is_none_or(|e| i < e))
        .and_then(|i| {
            let q = rest[i + 5..].chars().next()?;
            let v = &rest[i + 5 + q.len_utf8()..];
            v.find(q).map(|j| &v[..j])
        });
    let line = text[..start].matches('\n').count() + 1;
    match name {
        Some(n) => format!(" inside <{tag} name=\"{n}\"> (line {line})"),
        None => format!(" inside a <{tag}> (line {line})"),
    }
}

/// The name of the last element opened in `text` (for a truncated file's message).
fn last_open_tag(text: &str) -> Option<&str> {
    let start = text.rfind('<')? + 1;
    let name: &str = text[start..]
        .split(|c: char| c.is_whitespace() || c == '>' || c == '/')
        .next()?;
    let ok = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_alphanumeric() || matches!(c, '_' | '-' | ':' | '.'));
    ok.then_some(name)
}

/// True for a child of the root element (a `<link>`, `<joint>`, ...).
fn is_top(node: Node) -> bool {
    node.parent_element()
        .is_some_and(|p| p.parent().is_some_and(|r| r.is_root()))
}

/// The element a node belongs to for messages: its enclosing top-level element
/// (`<link name="x">`, `<joint name="x">`, `<material name="x">`), or the node's own tag.
fn owner(node: Node) -> String {
    match node.ancestors().find(|a| is_top(*a)) {
        Some(a) => {
            let tag = a.tag_name().name();
            match a.attribute("name") {
                Some(name) => format!("<{tag} name=\"{name}\">"),
                None => format!("<{tag}>"),
            }
        }
        None => format!("<{}>", node.tag_name().name()),
    }
}

/// The elements from below the owner down to `node`, e.g. `<inertial><mass` (no closing
/// `>`: the caller adds an attribute name or `>`); empty for the owner itself.
fn inner_path(node: Node) -> String {
    if is_top(node) || node.is_root() {
        return String::new();
    }
    let mut tags: Vec<&str> = node
        .ancestors()
        .take_while(|a| !is_top(*a) && !a.is_root())
        .filter(|a| a.is_element())
        .map(|a| a.tag_name().name())
        .collect();
    tags.reverse();
    let mut path = String::new();
    for (i, t) in tags.iter().enumerate() {
        path.push('<');
        path.push_str(t);
        if i + 1 < tags.len() {
            path.push('>');
        }
    }
    path
}

/// Checks the document's structure and numbers (see the module documentation) and
/// returns where its named elements are.
pub(super) fn check(doc: &Document, source: &str) -> Result<Positions, RobotError> {
    let at = |node: Node| node.range().start;
    let err = |node: Node, problem: String| located(doc, source, at(node), owner(node), problem);
    let root = doc.root_element();
    let root_tag = root.tag_name().name();
    if root_tag != "robot" {
        let what = match root_tag {
            "sdf" => "this is an SDFormat (SDF) file, and vinebench reads URDF (a <robot> \
                      root element); convert the model to URDF first (for example with the \
                      ROS 2 package sdformat_urdf), or describe it in URDF directly"
                .to_string(),
            "mujoco" => "this is an MJCF (MuJoCo) file, and vinebench reads URDF (a <robot> \
                         root element); vinebench generates the MuJoCo model from the URDF"
                .to_string(),
            other => format!("expected the URDF root element <robot>, found <{other}>"),
        };
        return Err(located(
            doc,
            source,
            at(root),
            format!("<{root_tag}>"),
            what,
        ));
    }

    // Nesting depth, in document order (parents come before their children).
    let mut depth: Vec<u32> = Vec::new();
    for node in doc.descendants() {
        let id = node.id().get_usize();
        let d = node
            .parent()
            .and_then(|p| depth.get(p.id().get_usize()).copied())
            .map_or(0, |d| d + 1);
        if depth.len() <= id {
            depth.resize(id + 1, 0);
        }
        depth[id] = d;
        if d as usize > MAX_URDF_DEPTH {
            return Err(err(
                node,
                format!(
                    "elements nested more than {MAX_URDF_DEPTH} deep (MAX_URDF_DEPTH); a URDF \
                     needs about 6 levels"
                ),
            ));
        }
    }
    drop(depth);

    let (mut links, mut joints) = (0usize, 0usize);
    let mut positions = Positions::new();
    for child in root.children().filter(|c| c.is_element()) {
        let tag = child.tag_name().name();
        let key = match tag {
            "link" | "joint" => {
                let count = if tag == "link" {
                    &mut links
                } else {
                    &mut joints
                };
                *count += 1;
                let (limit, name) = if tag == "link" {
                    (MAX_URDF_LINKS, "MAX_URDF_LINKS")
                } else {
                    (MAX_URDF_JOINTS, "MAX_URDF_JOINTS")
                };
                if *count > limit {
                    return Err(err(
                        child,
                        format!("more than {limit} <{tag}> elements ({name})"),
                    ));
                }
                let Some(n) = child.attribute("name") else {
                    return Err(err(child, format!("<{tag}> needs a name attribute")));
                };
                Some(format!("<{tag} name=\"{n}\">"))
            }
            "gazebo" => child
                .attribute("reference")
                .map(|r| format!("<gazebo reference=\"{r}\">")),
            "transmission" => child
                .attribute("name")
                .map(|n| format!("<transmission name=\"{n}\">")),
            _ => None,
        };
        if let Some(key) = key {
            positions.entry(key).or_insert(at(child));
        }
        if tag == "gazebo" {
            for p in child.children().filter(|c| c.has_tag_name("plugin")) {
                if let Some(n) = p.attribute("name") {
                    positions
                        .entry(format!("<plugin name=\"{n}\">"))
                        .or_insert(at(p));
                }
            }
        }
        if matches!(tag, "link" | "joint" | "material") {
            check_element(doc, source, child)?;
        }
    }
    Ok(positions)
}

/// The numbers, required attributes and children of one `<link>`, `<joint>` or
/// top-level `<material>` element.
fn check_element(doc: &Document, source: &str, top: Node) -> Result<(), RobotError> {
    // `what` continues the node's path: `>: missing ...`, ` value>: expected ...`.
    let err = |node: Node, at: usize, what: String| {
        let path = inner_path(node);
        let problem = if path.is_empty() {
            what.trim_start_matches(['>', ':', ' ']).to_string()
        } else {
            format!("{path}{what}")
        };
        located(doc, source, at, owner(node), problem)
    };
    let tag = top.tag_name().name();
    if tag == "joint" {
        match top.attribute("type") {
            Some(t) if JOINT_TYPES.contains(&t) => {}
            found => {
                return Err(err(
                    top,
                    top.range().start,
                    format!(
                        "attribute type: expected one of {}, found {}",
                        JOINT_TYPES.join(", "),
                        found.map_or("nothing".to_string(), |t| format!("\"{t}\""))
                    ),
                ));
            }
        }
        for role in ["parent", "child"] {
            let link = top
                .children()
                .find(|c| c.has_tag_name(role))
                .and_then(|c| c.attribute("link").map(|l| (c, l)));
            if link.is_none_or(|(_, l)| l.is_empty()) {
                return Err(err(
                    top,
                    top.range().start,
                    format!("needs a <{role} link=\"...\"> element"),
                ));
            }
        }
    }
    for node in top.descendants().filter(|n| n.is_element()) {
        let name = node.tag_name().name();
        match name {
            "inertial" => {
                for needed in ["mass", "inertia"] {
                    if !node.children().any(|c| c.has_tag_name(needed)) {
                        return Err(err(
                            node,
                            node.range().start,
                            format!(
                                ">: missing <{needed}> (an <inertial> needs <mass> and \
                                 <inertia>)"
                            ),
                        ));
                    }
                }
            }
            "visual" | "collision" if !node.children().any(|c| c.has_tag_name("geometry")) => {
                return Err(err(
                    node,
                    node.range().start,
                    ">: missing <geometry>".to_string(),
                ));
            }
            "geometry" => {
                let shapes = node
                    .children()
                    .filter(|c| c.is_element() && SHAPES.contains(&c.tag_name().name()))
                    .count();
                if shapes != 1 {
                    return Err(err(
                        node,
                        node.range().start,
                        format!(
                            ">: expected exactly one of <{}>, found {shapes}",
                            SHAPES.join(">, <")
                        ),
                    ));
                }
            }
            _ => {}
        }
        for a in NUMERIC.iter().filter(|a| a.element == name) {
            let Some(attribute) = node.attribute_node(a.attribute) else {
                if a.required {
                    return Err(err(
                        node,
                        node.range().start,
                        format!(
                            ">: missing attribute {}=\"...\" ({})",
                            a.attribute, a.meaning
                        ),
                    ));
                }
                continue;
            };
            let value = attribute.value();
            let numbers: Vec<Option<f64>> = value
                .split_whitespace()
                .map(|w| w.parse::<f64>().ok())
                .collect();
            let bad = numbers.len() != a.count
                || numbers.iter().any(|n| match n {
                    Some(x) => x.is_nan() || (x.is_infinite() && !a.infinite_ok),
                    None => true,
                });
            if bad {
                let expected = if a.count == 1 {
                    "a finite number".to_string()
                } else {
                    format!("{} finite numbers separated by spaces", a.count)
                };
                return Err(err(
                    node,
                    attribute.range().start,
                    format!(
                        " {}>: expected {expected} ({}), found \"{value}\"",
                        a.attribute, a.meaning
                    ),
                ));
            }
        }
    }
    Ok(())
}
