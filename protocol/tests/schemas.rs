//! The JSON Schemas published in `protocol/schemas/` are the types' own (schemars): a changed
//! message type with a stale schema fails here. `UPDATE_SCHEMAS=1 cargo test --release -p
//! protocol --features schema --test schemas` rewrites them.
#![cfg(feature = "schema")]

use std::path::Path;

use protocol::*;

#[test]
fn published_schemas_are_the_types_schemas() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("schemas");
    let update = std::env::var_os("UPDATE_SCHEMAS").is_some();
    if update {
        std::fs::create_dir_all(&dir).unwrap();
    }
    let schemas = [
        ("CoordinatorStatus", schemars::schema_for!(CoordinatorStatus)),
        ("TickDiagnostics", schemars::schema_for!(TickDiagnostics)),
        ("AgentStatus", schemars::schema_for!(AgentStatus)),
        ("GroundTruth", schemars::schema_for!(GroundTruth)),
        ("TaskReferences", schemars::schema_for!(TaskReferences)),
        ("PerturbationRequest", schemars::schema_for!(PerturbationRequest)),
        ("RobotDescription", schemars::schema_for!(RobotDescription)),
        ("RobotState", schemars::schema_for!(RobotState)),
        ("DynamicsTerms", schemars::schema_for!(DynamicsTerms)),
        ("TorqueCommand", schemars::schema_for!(TorqueCommand)),
        ("DriveCommand", schemars::schema_for!(DriveCommand)),
        ("ContactSet", schemars::schema_for!(ContactSet)),
    ];
    for (name, schema) in schemas {
        let text = serde_json::to_string_pretty(&schema).unwrap() + "\n";
        let path = dir.join(format!("{name}.json"));
        if update {
            std::fs::write(&path, &text).unwrap();
        } else {
            let published = std::fs::read_to_string(&path).unwrap_or_default();
            assert!(published == text, "protocol/schemas/{name}.json differs from the type (rewrite with UPDATE_SCHEMAS=1)");
        }
        // The schema names every field of the message's JSON form.
        let props = schema.as_value()["properties"].as_object().map(|p| p.len()).unwrap_or(0);
        assert!(props >= 2, "{name}: {props} properties");
    }
}
