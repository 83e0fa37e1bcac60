//! The control socket's protocol: JSON lines, one request a line from the client, one answer
//! a line from the run (docs/design/seams.md). A `subscribe` turns the connection into
//! the run's event stream, one event a line, until either side closes it.

use crate::runtime::forcing::ForceOrder;
use crate::runtime::requests::Drive;
use crate::runtime::snapshot::RigSnapshot;
use serde::{Deserialize, Serialize};

/// The protocol's version, in `hello`; raised when a request or an answer changes meaning.
pub const PROTOCOL_VERSION: u32 = 1;

/// The longest request line read; a longer one is answered with an error and the connection
/// closed.
pub const MAX_REQUEST: usize = 4096;

/// What a client asks, as the `request` field of its line.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "request", rename_all = "snake_case")]
pub enum ClientRequest {
    /// Who the run is (answered without the loop).
    Hello,
    /// The run as it stands (`RigSnapshot`).
    Status,
    /// Stop the run as SIGTERM would.
    Stop,
    /// Send the run's events from now on.
    Subscribe,
    /// Act on a simulated device (`{"request":"drive","device":"panel","action":"press",
    /// "name":"S12"}`), at the next tick boundary.
    Drive(Drive),
    /// Force a point (`{"request":"force","point":"io.DO3","value":true,"for":"5m"}`), where
    /// rig.toml allows it (`runtime::forcing`).
    Force(ForceOrder),
    /// End a force (`{"request":"unforce","point":"io.DO3"}`).
    Unforce {
        /// `DEVICE.POINT`.
        point: String,
    },
    /// Reload the script (`{"request":"reload"}`), or swap in another
    /// (`{"request":"reload","script":"/abs/path.rhai"}`): read, checked and tested off the
    /// loop, swapped at a tick boundary; answered done, or refused and why.
    Reload {
        /// The script to swap in, an absolute path (none: the run's own file again).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        script: Option<String>,
    },
}

/// Who a run is: answered to `hello`, and what `rigscript list` shows.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Hello {
    /// `PROTOCOL_VERSION`.
    pub protocol: u32,
    /// The rig's name.
    pub rig: String,
    /// The runner's process id.
    pub pid: u32,
    /// The script's file, as given to `run`.
    pub script: String,
    /// The rig.toml, as given to `run` (none: `--sim` alone).
    pub config: Option<String>,
    /// When the run started, RFC 3339.
    pub started: String,
}

/// One answer line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reply {
    /// Whether the request was done.
    pub ok: bool,
    /// Why not, when not.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub error: Option<String>,
    /// The answer to `hello`.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub hello: Option<Hello>,
    /// The answer to `status`.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub status: Option<RigSnapshot>,
}

impl Reply {
    /// Done, nothing to tell.
    pub fn done() -> Self {
        Self {
            ok: true,
            error: None,
            hello: None,
            status: None,
        }
    }

    /// Not done, and why.
    pub fn refused(why: impl Into<String>) -> Self {
        Self {
            ok: false,
            error: Some(why.into()),
            ..Self::done()
        }
    }

    /// The line to send, newline included.
    pub fn line(&self) -> String {
        let mut text = serde_json::to_string(self).unwrap_or_else(|e| {
            format!(r#"{{"ok":false,"error":"cannot write the answer: {e}"}}"#)
        });
        text.push('\n');
        text
    }
}

/// Reads a request line, or says in words what is wrong with it.
pub fn parse_request(line: &str) -> Result<ClientRequest, String> {
    serde_json::from_str(line.trim()).map_err(|e| {
        format!(
            "not a request ({e}); send one JSON object a line: {{\"request\": \"hello\"}}, \
             \"status\", \"stop\", \"reload\", \"subscribe\", \"drive\", \"force\" or \"unforce\""
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::forcing::ForceValue;
    use crate::runtime::requests::FieldAction;

    #[test]
    fn requests_read_from_their_json_lines_and_garbage_is_told() {
        assert_eq!(
            parse_request("{\"request\":\"status\"}\n"),
            Ok(ClientRequest::Status)
        );
        assert_eq!(
            parse_request(r#" {"request": "subscribe"} "#),
            Ok(ClientRequest::Subscribe)
        );
        assert_eq!(
            parse_request(
                r#"{"request":"drive","device":"io","action":"set_input","channel":3,"on":true}"#
            ),
            Ok(ClientRequest::Drive(Drive {
                device: "io".into(),
                action: FieldAction::SetInput {
                    channel: 3,
                    on: true
                }
            }))
        );
        assert!(parse_request(r#"{"request":"drive","device":"io","action":"melt"}"#).is_err());
        assert_eq!(
            parse_request(r#"{"request":"force","point":"io.DO3","value":true,"for":"5m"}"#),
            Ok(ClientRequest::Force(ForceOrder {
                point: "io.DO3".into(),
                value: ForceValue::On(true),
                duration: "5m".into(),
                overrides: Vec::new(),
            }))
        );
        assert_eq!(
            parse_request(r#"{"request":"force","point":"io.outputs","value":5,"for":"1s"}"#)
                .map(|r| matches!(r, ClientRequest::Force(o) if o.value == ForceValue::Byte(5))),
            Ok(true)
        );
        assert_eq!(
            parse_request(r#"{"request":"unforce","point":"io.DO3"}"#),
            Ok(ClientRequest::Unforce {
                point: "io.DO3".into()
            })
        );
        let e = parse_request("{\"request\":\"format_disk\"}").unwrap_err();
        assert!(
            e.contains("not a request") && e.contains("\"status\""),
            "{e}"
        );
        assert!(parse_request("\u{0}\u{1}garbage").is_err());
        assert_eq!(
            parse_request(r#"{"request":"reload"}"#),
            Ok(ClientRequest::Reload { script: None })
        );
        assert_eq!(
            parse_request(r#"{"request":"reload","script":"/r/b.rhai"}"#),
            Ok(ClientRequest::Reload {
                script: Some("/r/b.rhai".into())
            })
        );
    }

    #[test]
    fn replies_are_one_line_and_leave_out_what_they_do_not_carry() {
        let line = Reply::refused("no").line();
        assert_eq!(line, "{\"ok\":false,\"error\":\"no\"}\n");
        let back: Reply = serde_json::from_str(&line).unwrap();
        assert_eq!(back, Reply::refused("no"));
        assert_eq!(Reply::done().line(), "{\"ok\":true}\n");
    }
}
