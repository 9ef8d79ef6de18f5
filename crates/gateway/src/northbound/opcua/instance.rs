//! The box as an OPC 40501-1 `MachineToolType` instance: its object organised by Machinery's
//! `Machines` folder, the type's mandatory components (`Identification`, `Monitoring`,
//! `Notification`, `Production`) typed after the companion specification and with its browse
//! names, and the Identification properties from `[opcua.identification]`. The object is an event
//! notifier: the faults' alarms are raised on it. The variables the
//! status fills are created below these objects later, on first sight (`server::Space`).
//!
//! Node ids: the box's own namespace, `Machines/<box>/<path>` (what clients of earlier versions
//! address); browse names and type definitions: the companion namespaces.

use opcua::nodes::ReferenceDirection;
use opcua::server::address_space::{
    AccessLevel, AddressSpace, EventNotifier, ObjectBuilder, VariableBuilder,
};
use opcua::types::{
    DataTypeId, LocalizedText, NodeId, ObjectId, QualifiedName, ReferenceTypeId, VariableTypeId,
    Variant,
};

use super::Identification;
use super::nodesets::{
    MACHINE_TOOL_IDENTIFICATION_TYPE, MACHINE_TOOL_TYPE, MACHINES_FOLDER, MONITORING_TYPE,
    NOTIFICATION_TYPE, PRODUCTION_TYPE,
};

/// Namespace indices the server gave the box's and the companion namespaces.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Namespaces {
    pub own: u16,
    pub di: u16,
    pub machinery: u16,
    pub machine_tool: u16,
}

/// Create the box `box_name` (node id `root` in the own namespace) and its mandatory components.
pub(crate) fn insert(
    s: &mut AddressSpace,
    ns: Namespaces,
    root: &str,
    box_name: &str,
    ident: &Identification,
) {
    let machines = NodeId::new(ns.machinery, MACHINES_FOLDER);
    let id = NodeId::new(ns.own, root.to_string());
    ObjectBuilder::new(&id, QualifiedName::new(ns.own, box_name), box_name)
        .description("The machine tool whose volumetric error the retrocomp box compensates")
        .has_type_definition(NodeId::new(ns.machine_tool, MACHINE_TOOL_TYPE))
        .organized_by(machines)
        // The faults' Alarms & Conditions events (`alarms.rs`) come from this object; HasNotifier
        // from `Server` is how a client subscribed to the server's events finds it (Part 3 §7.16).
        .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
        .reference(
            ObjectId::Server,
            ReferenceTypeId::HasNotifier,
            ReferenceDirection::Inverse,
        )
        .insert(s);
    let components = [
        ("Identification", ns.di, MACHINE_TOOL_IDENTIFICATION_TYPE),
        ("Monitoring", ns.machine_tool, MONITORING_TYPE),
        ("Notification", ns.machine_tool, NOTIFICATION_TYPE),
        ("Production", ns.machine_tool, PRODUCTION_TYPE),
    ];
    for (name, browse_ns, type_id) in components {
        // `Identification` is an AddIn of the type (HasAddIn, a HasComponent), the others components.
        let b = ObjectBuilder::new(
            &NodeId::new(ns.own, format!("{root}/{name}")),
            QualifiedName::new(browse_ns, name),
            name,
        )
        .has_type_definition(NodeId::new(ns.machine_tool, type_id));
        let b = if name == "Identification" {
            b.reference(
                id.clone(),
                ReferenceTypeId::HasAddIn,
                ReferenceDirection::Inverse,
            )
        } else {
            b.component_of(id.clone())
        };
        b.insert(s);
    }
    let ident_id = NodeId::new(ns.own, format!("{root}/Identification"));
    for (name, browse_ns, value) in nameplate(ns, ident) {
        let (data_type, value) = match value {
            Plate::Text(t) => (
                DataTypeId::LocalizedText,
                Variant::from(LocalizedText::new("", t)),
            ),
            Plate::Str(t) => (DataTypeId::String, Variant::from(t)),
            Plate::Year(y) => (DataTypeId::UInt16, Variant::UInt16(y)),
        };
        let read = AccessLevel::CURRENT_READ;
        VariableBuilder::new(
            &NodeId::new(ns.own, format!("{root}/Identification/{name}")),
            QualifiedName::new(browse_ns, name),
            name,
        )
        .data_type(data_type)
        .value(value)
        .access_level(read)
        .user_access_level(read)
        .has_type_definition(VariableTypeId::PropertyType)
        .property_of(ident_id.clone())
        .insert(s);
    }
}

enum Plate<'a> {
    Text(&'a str),
    Str(&'a str),
    Year(u16),
}

/// The Identification properties given: (browse name, its namespace, value). Manufacturer,
/// SerialNumber and ProductInstanceUri are always there (the config refuses a section without).
fn nameplate<'a>(ns: Namespaces, id: &'a Identification) -> Vec<(&'static str, u16, Plate<'a>)> {
    let mut out = Vec::with_capacity(6);
    let mandatory = |v: &'a Option<String>| v.as_deref().unwrap_or_default();
    out.push((
        "Manufacturer",
        ns.di,
        Plate::Text(mandatory(&id.manufacturer)),
    ));
    out.push((
        "SerialNumber",
        ns.di,
        Plate::Str(mandatory(&id.serial_number)),
    ));
    out.push((
        "ProductInstanceUri",
        ns.di,
        Plate::Str(mandatory(&id.product_instance_uri)),
    ));
    if let Some(m) = &id.model {
        out.push(("Model", ns.di, Plate::Text(m)));
    }
    if let Some(y) = id.year_of_construction {
        out.push(("YearOfConstruction", ns.machinery, Plate::Year(y)));
    }
    if let Some(l) = &id.location {
        out.push(("Location", ns.machinery, Plate::Str(l)));
    }
    out
}
