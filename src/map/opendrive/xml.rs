//! A small element tree read with quick-xml, with the line of every element, so every
//! OpenDRIVE error and warning can name its line.
//!
//! OpenDRIVE files are nested (road > lanes > laneSection > right > lane > width) and refer
//! across the file (links, junctions), so a tree is the simplest reader; building it is one
//! pass over the text (O(size)), as [`crate::map::commonroad`] does for CommonRoad.

use std::path::Path as FsPath;

use quick_xml::Reader;
use quick_xml::events::Event;

use crate::map::error::{Location, MapError};

/// A parsed XML element.
#[derive(Debug, Default)]
pub(crate) struct Element {
    /// Tag name.
    pub name: String,
    /// Attributes in file order.
    pub attrs: Vec<(String, String)>,
    /// Text and CDATA content, concatenated.
    pub text: String,
    /// Child elements in file order.
    pub children: Vec<Element>,
    /// 1-based line of the start tag.
    pub line: usize,
}

impl Element {
    /// The value of attribute `name`.
    pub fn attr(&self, name: &str) -> Option<&str> {
        self.attrs.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }

    /// The first child called `name`.
    pub fn child(&self, name: &str) -> Option<&Element> {
        self.children.iter().find(|c| c.name == name)
    }

    /// All children called `name`.
    pub fn children<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Element> + 'a {
        self.children.iter().filter(move |c| c.name == name)
    }
}

/// Parse `text` into its root element (which must be `<OpenDRIVE>`).
pub(crate) fn parse_tree(text: &str, source: &FsPath) -> Result<Element, MapError> {
    parse_root(text, source)?.filter(|r| r.name == "OpenDRIVE").ok_or_else(|| MapError::Xml {
        at: Location { file: source.to_path_buf(), line: 0 },
        message: "no <OpenDRIVE> root element; this is not an OpenDRIVE (.xodr) file".into(),
    })
}

/// Parse `text` into its root element, whatever its name (`None` for a file without one); the
/// SUMO reader ([`crate::map::sumo`]) shares this tree.
pub(crate) fn parse_root(text: &str, source: &FsPath) -> Result<Option<Element>, MapError> {
    let mut reader = Reader::from_str(text);
    reader.config_mut().trim_text(true);
    let bytes = text.as_bytes();
    let (mut line, mut counted) = (1usize, 0usize);
    // Lines are counted incrementally: the reader only moves forward, so the whole file is
    // scanned for newlines once.
    let mut line_at = |offset: usize| {
        let offset = offset.min(bytes.len());
        if offset > counted {
            line += bytes[counted..offset].iter().filter(|&&b| b == b'\n').count();
            counted = offset;
        }
        line
    };
    let xml_error =
        |line: usize, message: String| MapError::Xml { at: Location { file: source.to_path_buf(), line }, message };
    let mut stack: Vec<Element> = vec![Element::default()];
    loop {
        let start = reader.buffer_position() as usize;
        let event =
            reader.read_event().map_err(|e| xml_error(line_at(reader.error_position() as usize), e.to_string()))?;
        let skip = text.get(start..).and_then(|rest| rest.find('<')).unwrap_or(0);
        let elem_line = line_at(start + skip);
        match event {
            Event::Start(ref e) | Event::Empty(ref e) => {
                let mut el = Element { name: e.name().as_ref().to_string(), line: elem_line, ..Default::default() };
                for a in e.attributes().with_checks(false) {
                    let a = a.map_err(|err| xml_error(elem_line, err.to_string()))?;
                    let v = a
                        .normalized_value(quick_xml::XmlVersion::Implicit1_0)
                        .map_err(|err| xml_error(elem_line, err.to_string()))?;
                    el.attrs.push((a.key.as_ref().to_string(), v.into_owned()));
                }
                if matches!(event, Event::Empty(_)) {
                    if let Some(parent) = stack.last_mut() {
                        parent.children.push(el);
                    }
                } else {
                    stack.push(el);
                }
            }
            Event::Text(t) => {
                if let Some(top) = stack.last_mut() {
                    top.text.push_str(&t.xml10_content());
                }
            }
            Event::CData(t) => {
                if let Some(top) = stack.last_mut() {
                    top.text.push_str(&t.xml10_content());
                }
            }
            Event::End(_) if stack.len() > 1 => {
                let el = stack.pop().unwrap_or_default();
                if let Some(parent) = stack.last_mut() {
                    parent.children.push(el);
                }
            }
            Event::Eof => break,
            _ => {}
        }
    }
    if stack.len() > 1 {
        let open = &stack[stack.len() - 1];
        return Err(xml_error(open.line, format!("<{}> is never closed (the file ends early)", open.name)));
    }
    let mut root = stack.swap_remove(0);
    Ok(root.children.pop())
}
