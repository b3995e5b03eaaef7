//! `GET /fleet`: the other gateways on the zenoh fabric, for the status page's fleet section.

use axum::extract::State;
use axum::Json;

use crate::api::model::Fleet;
use crate::api::ApiState;

/// The other gateways this one sees on zenoh (name, zenoh id, online, a link to its page).
#[utoipa::path(
    get,
    path = "/fleet",
    tag = "status",
    responses((status = 200, description = "The other gateways of the fleet", body = Fleet))
)]
pub(crate) async fn get_fleet(State(state): State<ApiState>) -> Json<Fleet> {
    Json(Fleet {
        gateways: state.backend().fleet(),
    })
}
