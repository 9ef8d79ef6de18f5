//! The companion specifications' information models the box is an instance of: OPC 40501-1
//! Machine Tools and OPC 40001-1 Machinery with what they require (DI, IA, ISA-95 Job Control,
//! Machinery Jobs), imported from the OPC Foundation's NodeSet2 XML files at start. The files are
//! vendored unchanged under `crates/gateway/assets/opcua/nodesets/` (SOURCE.md: where from,
//! licence, checksums) and embedded in the binary.
//!
//! Node ids of the types and objects the box uses are the numeric ids those files give them,
//! in their own namespace (the server assigns each namespace URI its index at start).

use opcua::nodes::NodeSet2Import;
use opcua::nodes::{ImportedItem, NodeSetImport};
use opcua::types::NodeSetNamespaceMapper;

pub(crate) const DI_URI: &str = "http://opcfoundation.org/UA/DI/";
pub(crate) const MACHINERY_URI: &str = "http://opcfoundation.org/UA/Machinery/";
pub(crate) const MACHINE_TOOL_URI: &str = "http://opcfoundation.org/UA/MachineTool/";

/// Machinery: `Objects/Machines`, the folder every machine of the server is organised in.
pub(crate) const MACHINES_FOLDER: u32 = 1001;
/// MachineTool: the types of the box and of its mandatory components.
pub(crate) const MACHINE_TOOL_TYPE: u32 = 13;
pub(crate) const MACHINE_TOOL_IDENTIFICATION_TYPE: u32 = 11;
pub(crate) const MONITORING_TYPE: u32 = 14;
pub(crate) const NOTIFICATION_TYPE: u32 = 7;
pub(crate) const PRODUCTION_TYPE: u32 = 21;

/// (file, its text), each after the files it requires.
const FILES: [(&str, &str); 6] = [
    (
        "Opc.Ua.Di.NodeSet2.xml",
        include_str!("../../../assets/opcua/nodesets/Opc.Ua.Di.NodeSet2.xml"),
    ),
    (
        "Opc.Ua.IA.NodeSet2.xml",
        include_str!("../../../assets/opcua/nodesets/Opc.Ua.IA.NodeSet2.xml"),
    ),
    (
        "Opc.Ua.Machinery.NodeSet2.xml",
        include_str!("../../../assets/opcua/nodesets/Opc.Ua.Machinery.NodeSet2.xml"),
    ),
    (
        "opc.ua.isa95-jobcontrol.nodeset2.xml",
        include_str!("../../../assets/opcua/nodesets/opc.ua.isa95-jobcontrol.nodeset2.xml"),
    ),
    (
        "Opc.Ua.Machinery.Jobs.Nodeset2.xml",
        include_str!("../../../assets/opcua/nodesets/Opc.Ua.Machinery.Jobs.Nodeset2.xml"),
    ),
    (
        "Opc.Ua.MachineTool.NodeSet2.xml",
        include_str!("../../../assets/opcua/nodesets/Opc.Ua.MachineTool.NodeSet2.xml"),
    ),
];

/// Every companion file as an import, then the box's own (empty) namespace `own_uri`: one node
/// manager holds them all, so the box's nodes and the Machinery folder they hang in are in the
/// same address space. Err: the file that does not parse (a broken build, not a field problem).
pub(crate) fn imports(own_uri: &str) -> Result<Vec<Box<dyn NodeSetImport>>, String> {
    let mut out: Vec<Box<dyn NodeSetImport>> = Vec::with_capacity(FILES.len() + 1);
    for (name, xml) in FILES {
        let inner = NodeSet2Import::new_str("en", &unwrap_byte_strings(xml), Vec::new())
            .map_err(|e| format!("opcua: the nodeset {name} does not load: {e}"))?;
        out.push(Box::new(Quiet(inner)));
    }
    out.push(Box::new(Own(own_uri.to_string())));
    Ok(out)
}

/// `xml` with the base64 text of every `<ByteString>` value on one line: the published files wrap
/// it (the deprecated type dictionaries), and async-opcua 0.19 decodes only unwrapped base64 (it
/// would log each as an invalid byte string and drop its value).
fn unwrap_byte_strings(xml: &str) -> String {
    const CLOSE: &str = "</ByteString>";
    let mut out = String::with_capacity(xml.len());
    let mut rest = xml;
    while let Some(open) = rest.find("<ByteString") {
        let Some(tag_len) = rest[open..].find('>') else {
            break;
        };
        let body = open + tag_len + 1;
        out.push_str(&rest[..body]);
        rest = &rest[body..];
        // `<ByteString/>` has no body.
        if out.ends_with("/>") {
            continue;
        }
        let Some(len) = rest.find(CLOSE) else {
            break;
        };
        out.extend(rest[..len].chars().filter(|c| !c.is_whitespace()));
        rest = &rest[len..];
    }
    out.push_str(rest);
    out
}

/// A NodeSet2 file's import, registering its namespaces without printing them on stdout (which
/// async-opcua's own `register_namespaces` does: stdout is the CLI's, not the library's).
struct Quiet(NodeSet2Import);

impl NodeSetImport for Quiet {
    fn register_namespaces(&self, namespaces: &mut NodeSetNamespaceMapper<'_>) {
        // The file's namespace array: index 1 is its first URI (0 is always the base namespace).
        for (i, ns) in (1u16..).zip(self.0.get_own_namespaces().iter()) {
            namespaces.add_namespace(ns, i);
        }
    }
    fn get_own_namespaces(&self) -> Vec<String> {
        self.0.get_own_namespaces()
    }
    fn load<'a>(
        &'a self,
        namespaces: &'a NodeSetNamespaceMapper<'_>,
    ) -> Box<dyn Iterator<Item = ImportedItem> + 'a> {
        self.0.load(namespaces)
    }
}

/// The box's namespace: registered and owned, its nodes created at run time.
struct Own(String);

impl NodeSetImport for Own {
    fn register_namespaces(&self, namespaces: &mut NodeSetNamespaceMapper<'_>) {
        namespaces.add_namespace(&self.0, 1);
    }
    fn get_own_namespaces(&self) -> Vec<String> {
        vec![self.0.clone()]
    }
    fn load<'a>(
        &'a self,
        _namespaces: &'a NodeSetNamespaceMapper<'_>,
    ) -> Box<dyn Iterator<Item = ImportedItem> + 'a> {
        Box::new(std::iter::empty())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrapped_base64_is_joined_and_nothing_else_changes() {
        let xml = "<a><ByteString xmlns=\"x\">QUJD\n  REVG\r\n</ByteString><b> k  l </b>\
                   <ByteString/><c>m n</c><ByteString>R0g=</ByteString></a>";
        assert_eq!(
            unwrap_byte_strings(xml),
            "<a><ByteString xmlns=\"x\">QUJDREVG</ByteString><b> k  l </b>\
             <ByteString/><c>m n</c><ByteString>R0g=</ByteString></a>"
        );
    }

    #[test]
    fn every_companion_nodeset_loads_and_owns_its_namespace() {
        let imports = imports("urn:test").unwrap();
        let owned: Vec<String> = imports
            .iter()
            .map(|i| i.get_own_namespaces()[0].clone())
            .collect();
        assert_eq!(owned[0], DI_URI);
        assert_eq!(owned[2], MACHINERY_URI);
        assert_eq!(owned[5], MACHINE_TOOL_URI);
        assert_eq!(owned[6], "urn:test");
    }
}
