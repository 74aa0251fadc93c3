//! The OpenAPI document of the HTTP API, at `/api/openapi.json`: generated (utoipa) from the
//! annotations on the routes of [`super::api`] and [`super::intake`], and checked against the
//! routes the router serves.

use axum::response::{IntoResponse, Response};
use axum::Json;
use tessera_proto::view::{JobView, LogEntryView, LogLevel, LogPage, WorkerView};
use utoipa::OpenApi;

use super::{api, intake};

/// The OpenAPI document of these routes.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "tessera coordinator",
        description = "Render jobs over HTTP: submit a scene (after uploading the files it \
                       names), follow it, read its workers' log, pause, resume, reprioritise, \
                       cancel or retry it, and download its EXR. Every route needs the farm's \
                       token as `Authorization: Bearer TOKEN` when the coordinator has one."
    ),
    paths(
        openapi, api::list_jobs, intake::submit, api::job, api::cancel, api::pause, api::resume,
        api::priority, api::retry, api::logs, api::output_exr, super::preview_png,
        api::list_workers, api::drain, api::release, intake::asset_status, intake::upload_asset
    ),
    components(schemas(
        api::ApiError, intake::SubmitBody, intake::DenoiseRequest, intake::Submitted, api::PriorityBody, api::Retried,
        LogPage, LogEntryView, LogLevel, intake::Held, api::Drained, api::Released, JobView,
        WorkerView
    )),
    modifiers(&Bearer),
    security(("bearer" = []))
)]
struct Api;

/// The bearer-token scheme every route uses.
struct Bearer;

impl utoipa::Modify for Bearer {
    fn modify(&self, doc: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
        doc.components
            .get_or_insert_with(Default::default)
            .add_security_scheme(
                "bearer",
                SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
            );
    }
}

/// This document.
#[utoipa::path(get, path = "/api/openapi.json", responses((status = 200, description = "The OpenAPI 3.1 document of this API")))]
pub(super) async fn openapi() -> Response {
    Json(Api::openapi()).into_response()
}

/// The routes as the document lists them (method, path), for the test that it lists every one.
#[cfg(test)]
fn documented() -> Vec<(String, String)> {
    let doc = Api::openapi();
    let mut out = Vec::new();
    for (path, item) in doc.paths.paths {
        for (method, op) in [
            ("GET", item.get.is_some()),
            ("POST", item.post.is_some()),
            ("PUT", item.put.is_some()),
        ] {
            if op {
                out.push((method.to_string(), path.clone()));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every `/api/` route the router serves is in the OpenAPI document, and the document
    /// lists nothing else: read from the router's own source, so a route added without its
    /// annotation fails here.
    #[test]
    fn the_document_lists_exactly_the_routes_served() {
        // Whitespace dropped, so that a route rustfmt wraps over several lines reads as one.
        let source: String = include_str!("mod.rs").split_whitespace().collect();
        let mut served: Vec<(String, String)> = Vec::new();
        for call in source.split(".route(\"/api/").skip(1) {
            let (path, rest) = call.split_once('"').expect("a quoted path");
            // This route's handlers: up to the next route.
            let handlers = rest.split(".route(").next().unwrap_or_default();
            for (method, name) in [("GET", "get("), ("POST", "post("), ("PUT", "put(")] {
                if handlers.contains(name) {
                    served.push((method.to_string(), format!("/api/{path}")));
                }
            }
        }
        let mut listed = documented();
        served.sort();
        listed.sort();
        assert!(served.len() >= 16, "{served:?}");
        assert_eq!(served, listed);
    }
}
