//! The OpenAPI document: valid JSON, every route of the router in it and nothing else, each
//! listed operation served, the changes marked as needing the bearer token.

use std::collections::BTreeSet;

use reqwest::Method;
use serde_json::Value;

use super::support::{start, TOKEN};

/// Every route the API serves.
const ROUTES: &[(&str, &str)] = &[
    ("get", "/healthz"),
    ("get", "/readyz"),
    ("get", "/api/v1/openapi.json"),
    ("get", "/api/v1/status"),
    ("get", "/api/v1/fleet"),
    ("get", "/api/v1/config"),
    ("put", "/api/v1/config"),
    ("post", "/api/v1/config/validate"),
    ("get", "/api/v1/config/lines/{line}"),
    ("put", "/api/v1/config/lines/{line}"),
    ("delete", "/api/v1/config/lines/{line}"),
    ("get", "/api/v1/lines"),
    ("get", "/api/v1/lines/{line}"),
    ("get", "/api/v1/lines/{line}/diag"),
    ("delete", "/api/v1/lines/{line}/diag"),
    ("get", "/api/v1/lines/{line}/telegrams"),
    ("post", "/api/v1/lines/{line}/telegrams/{seq}/ack"),
    ("post", "/api/v1/lines/{line}/send"),
    ("get", "/api/v1/lines/{line}/signals"),
    ("put", "/api/v1/lines/{line}/signals"),
    ("get", "/api/v1/lines/{line}/frames"),
    ("get", "/api/v1/lines/{line}/capture"),
    ("get", "/api/v1/tags"),
    ("get", "/api/v1/lines/{line}/devices/{device}/tags"),
    ("get", "/api/v1/lines/{line}/devices/{device}/tags/{tag}"),
    ("put", "/api/v1/lines/{line}/devices/{device}/tags/{tag}"),
];

fn operations(doc: &Value) -> BTreeSet<(String, String)> {
    let mut ops = BTreeSet::new();
    for (path, item) in doc["paths"].as_object().expect("paths") {
        for method in item.as_object().expect("path item").keys() {
            if ["get", "put", "post", "delete", "patch", "head"].contains(&method.as_str()) {
                ops.insert((method.clone(), path.clone()));
            }
        }
    }
    ops
}

#[tokio::test]
async fn the_document_lists_exactly_the_routes() {
    let api = start().await;
    let r = api.get("/api/v1/openapi.json").await;
    assert_eq!(r.status, 200);
    assert_eq!(r.header("content-type"), Some("application/json"));
    let doc: Value = serde_json::from_str(&r.text).expect("the document is JSON");
    assert!(
        doc["openapi"].as_str().is_some_and(|v| v.starts_with("3.")),
        "{}",
        doc["openapi"]
    );
    assert_eq!(doc["info"]["version"], env!("CARGO_PKG_VERSION"));

    let expected: BTreeSet<(String, String)> = ROUTES
        .iter()
        .map(|(m, p)| ((*m).to_owned(), (*p).to_owned()))
        .collect();
    assert_eq!(operations(&doc), expected);

    // The same document is available without a server.
    let offline = serde_json::to_value(gateway::api::openapi()).unwrap();
    assert_eq!(offline, doc);
}

#[tokio::test]
async fn changes_need_the_bearer_token_in_the_document() {
    let api = start().await;
    let doc = api.get("/api/v1/openapi.json").await.json;
    assert_eq!(
        doc["components"]["securitySchemes"]["bearer"]["scheme"],
        "bearer"
    );
    assert!(doc["components"]["schemas"]["ErrorBody"].is_object());
    for (method, path) in operations(&doc) {
        let op = &doc["paths"][&path][&method];
        let responses = op["responses"].as_object().unwrap();
        assert!(responses.contains_key("504"), "{method} {path}");
        if method == "get" {
            assert!(op.get("security").is_none(), "{method} {path}");
            continue;
        }
        assert_eq!(
            op["security"][0]["bearer"],
            Value::Array(vec![]),
            "{method} {path}"
        );
        for status in ["401", "403"] {
            let schema = &responses[status]["content"]["application/json"]["schema"]["$ref"];
            assert_eq!(
                schema, "#/components/schemas/ErrorBody",
                "{method} {path} {status}"
            );
        }
    }
}

/// Each operation of the document answers on the router: no "no route" and no 405.
#[tokio::test]
async fn every_documented_operation_is_served() {
    let api = start().await;
    api.gw.receive("ascii", b"x");
    for (method, path) in ROUTES {
        let concrete = path
            .replace(
                "{line}",
                if path.contains("{device}") {
                    "drive"
                } else {
                    "ascii"
                },
            )
            .replace("{device}", "atv71")
            .replace("{tag}", "lfrd")
            .replace("{seq}", "1");
        let method = Method::from_bytes(method.to_uppercase().as_bytes()).unwrap();
        let r = api
            .request(method.clone(), &concrete, Some(TOKEN), None)
            .await;
        assert_ne!(r.status, 405, "{method} {concrete}: {}", r.text);
        if r.status == 404 {
            assert!(
                !r.json["error"]["message"]
                    .as_str()
                    .unwrap_or_default()
                    .starts_with("no route"),
                "{method} {concrete} is not routed"
            );
        }
    }
}

/// What schemathesis found: an unused method answered 401 instead of 405, a value schema whose
/// `oneOf` branches overlap (an integer is a number), 400 answers that were not documented; and
/// a server without a token that the document said needed one.
#[tokio::test]
async fn the_document_matches_what_the_server_answers() {
    let api = start().await;
    for method in ["TRACE", "OPTIONS"] {
        let r = api
            .request(
                Method::from_bytes(method.as_bytes()).unwrap(),
                "/api/v1/status",
                None,
                None,
            )
            .await;
        assert_eq!(
            (r.status, r.code()),
            (405, "method_not_allowed"),
            "{method}"
        );
    }

    let doc = api.get("/api/v1/openapi.json").await.json;
    let value = &doc["components"]["schemas"]["ScalarValue"];
    let types: Vec<&str> = value["oneOf"]
        .as_array()
        .unwrap_or_else(|| panic!("oneOf: {value}"))
        .iter()
        .filter_map(|b| b["type"].as_str())
        .collect();
    assert_eq!(types, ["boolean", "number", "string"], "{value}");

    // A sequence number that is not a number answers 400, which the operation documents.
    let r = api
        .request(
            Method::POST,
            "/api/v1/lines/ascii/telegrams/-1/ack",
            Some(TOKEN),
            None,
        )
        .await;
    assert_eq!(r.status, 400, "{}", r.text);
    for (method, path) in operations(&doc) {
        let op = &doc["paths"][&path][&method];
        if op["parameters"].as_array().is_some_and(|p| !p.is_empty()) {
            assert!(
                op["responses"]["400"].is_object(),
                "{method} {path} has parameters but no 400"
            );
        }
    }

    // A server that accepts changes without a token documents no token and no 401; its 403 is
    // the Host and Origin check alone (which holds in every mode).
    let open = super::support::start_with(super::support::Setup {
        auth: gateway::api::Auth::insecure(),
        ..super::support::Setup::default()
    })
    .await;
    let doc = open.get("/api/v1/openapi.json").await.json;
    assert!(doc["components"]["securitySchemes"].get("bearer").is_none());
    for (method, path) in operations(&doc) {
        let op = &doc["paths"][&path][&method];
        assert!(op.get("security").is_none(), "{method} {path}");
        assert!(op["responses"].get("401").is_none(), "{method} {path} 401");
        let forbidden = op["responses"]["403"]["description"]
            .as_str()
            .unwrap_or_default();
        assert!(forbidden.contains("Host"), "{method} {path}: {forbidden}");
        assert_eq!(
            forbidden.contains("Origin"),
            method != "get",
            "{method} {path}: {forbidden}"
        );
        assert!(!forbidden.contains("token"), "{method} {path}: {forbidden}");
    }
}

/// `GET /fleet` of a gateway that sees no other (here: no zenoh at all) answers an empty list,
/// so that the status page shows no fleet section; the document describes its entries.
#[tokio::test]
async fn the_fleet_of_a_lone_gateway_is_empty() {
    let api = start().await;
    let r = api.get("/api/v1/fleet").await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json, serde_json::json!({"gateways": []}));
    let doc = api.get("/api/v1/openapi.json").await.json;
    let entry = &doc["components"]["schemas"]["FleetEntry"]["properties"];
    for field in ["key", "name", "zid", "host", "online", "since", "link"] {
        assert!(entry.get(field).is_some(), "FleetEntry.{field}: {entry}");
    }
}
