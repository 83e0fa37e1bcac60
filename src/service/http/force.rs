//! `POST /api/force` (`{"point":"io.DO3","value":true,"for":"5m"}`) and `DELETE
//! /api/force/POINT`: forcing from the page, checked against the snapshot first so each
//! refusal has its status (403 forcing off, 404 no such device, point or force, 400 a bad
//! value or duration), then asked of the loop (409 for what it refuses: held safe).

use super::api::{is_json, snapshot, unavailable};
use super::request::HttpRequest;
use super::response::Response;
use super::{Shared, ANSWER_WAIT};
use crate::runtime::forcing::{check_point, parse_for, ForceError, ForceOrder, Kind};
use crate::runtime::requests::{Answer, Request};
use crate::runtime::snapshot::{DeviceState, RigSnapshot};

/// Where a force is ended: `DELETE /api/force/io.DO3`.
pub(super) const UNFORCE_PREFIX: &str = "/api/force/";

/// `POST /api/force`.
pub(super) fn force(request: &HttpRequest, shared: &Shared, by: &str) -> Response {
    if !is_json(request) {
        return Response::error(415, "a force is sent as application/json");
    }
    let order: ForceOrder = match serde_json::from_slice(&request.body) {
        Ok(o) => o,
        Err(e) => {
            return Response::error(
                400,
                format!(
                    "{e}; a force is {{\"point\":\"io.DO3\",\"value\":true,\"for\":\"5m\"}} \
                     (value: true/false for a channel or switch, a byte for outputs, inputs, \
                     relay)"
                ),
            )
        }
    };
    let state = match snapshot(shared) {
        Ok(s) => s,
        Err(e) => return e,
    };
    let checked = allowed(&state)
        .and_then(|()| check_point(&order.point, order.value, &kinds(&state)))
        .and_then(|point| parse_for(&order.duration).map(|_| point));
    let point = match checked {
        Ok(p) => p,
        Err(e) => return refusal(&e),
    };
    let asked = Request::Force {
        order,
        by: by.to_string(),
    };
    answer(shared, asked, &point)
}

/// `DELETE /api/force/POINT`.
pub(super) fn unforce(point: &str, shared: &Shared, by: &str) -> Response {
    let state = match snapshot(shared) {
        Ok(s) => s,
        Err(e) => return e,
    };
    if let Err(e) = allowed(&state) {
        return refusal(&e);
    }
    if !state.forces.iter().any(|f| f.point == point) {
        return refusal(&ForceError::NotForced(point.to_string()));
    }
    let asked = Request::Unforce {
        point: point.to_string(),
        by: by.to_string(),
    };
    answer(shared, asked, point)
}

fn allowed(state: &RigSnapshot) -> Result<(), ForceError> {
    if state.forcing {
        Ok(())
    } else {
        Err(ForceError::NotAllowed)
    }
}

/// The rig's devices by kind, from the snapshot.
fn kinds(state: &RigSnapshot) -> Vec<(&str, Kind)> {
    state
        .devices
        .iter()
        .map(|(name, d)| {
            let kind = match d {
                DeviceState::C29u { .. } => Kind::C29u,
                DeviceState::Trc { .. } => Kind::Trc,
            };
            (name.as_str(), kind)
        })
        .collect()
}

fn refusal(e: &ForceError) -> Response {
    Response::error(e.status(), e)
}

fn answer(shared: &Shared, asked: Request, point: &str) -> Response {
    match shared.ask.ask(asked, ANSWER_WAIT) {
        Ok(Answer::Accepted) => {
            Response::json(200, &serde_json::json!({ "done": true, "point": point }))
        }
        Ok(Answer::Refused(why)) => Response::error(409, why),
        Ok(Answer::Snapshot(_)) => Response::error(503, "the run answered with a snapshot"),
        Err(e) => unavailable(&e),
    }
}
