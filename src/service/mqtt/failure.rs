//! A failed or refused MQTT connection in words for people: what the broker said, naming the
//! broker and the user, and what to check. The rig's client and `rigscript lab` both use it.

use rumqttc::v5::mqttbytes::v5::ConnectReturnCode;
use rumqttc::v5::{ConnectionError, StateError};

/// The user a message names when the connection gives none.
pub const ANONYMOUS: &str = "(anonymous)";

/// Who was connecting where, for the messages.
pub struct Peer<'a> {
    /// The broker, `HOST:PORT`.
    pub broker: &'a str,
    /// The user, or `(anonymous)`.
    pub user: &'a str,
    /// The host the broker's certificate must name.
    pub host: &'a str,
    /// Where the password comes from, as the user wrote it (`password_file / password_env`).
    pub password_from: &'a str,
}

/// A connection's failure in words naming the broker and the user.
pub fn describe(e: &ConnectionError, peer: &Peer) -> String {
    let Peer {
        broker,
        user,
        host,
        password_from,
    } = peer;
    match e {
        ConnectionError::ConnectionRefused(
            ConnectReturnCode::BadUserNamePassword | ConnectReturnCode::NotAuthorized,
        ) => format!(
            "broker {broker} refused user {user}: wrong user name or password, or not allowed \
             ({password_from})"
        ),
        ConnectionError::ConnectionRefused(
            ConnectReturnCode::UnsupportedProtocolVersion
            | ConnectReturnCode::RefusedProtocolVersion,
        ) => format!(
            "broker {broker} does not speak MQTT 5, which rigscript needs (Mosquitto \
             1.6 or later does)"
        ),
        ConnectionError::ConnectionRefused(code) => {
            format!("broker {broker} refused the connection of user {user}: {code:?}")
        }
        ConnectionError::Tls(t) if not_tls(t) => format!(
            "TLS to broker {broker} failed: {t}: the peer did not speak TLS (is the port a plain \
             MQTT port? mqtts:// needs the broker's TLS listener, 8883 by default; mqtt:// \
             speaks to a plain one)"
        ),
        ConnectionError::Tls(t) => format!(
            "TLS to broker {broker} failed: {t} (is ca_file the CA that signed the broker's \
             certificate, and does the certificate name {}?)",
            host
        ),
        ConnectionError::Io(io) => format!("cannot reach broker {broker}: {io}"),
        ConnectionError::Timeout(_) => {
            format!("broker {broker} did not answer the connection in time")
        }
        ConnectionError::NotConnAck(packet) => format!(
            "broker {broker} answered the connection with {packet:?}, not a CONNACK (does it \
             speak MQTT 5?)"
        ),
        ConnectionError::MqttState(StateError::ServerDisconnect {
            reason_code,
            reason_string,
        }) => format!(
            "broker {broker} ended the connection: {reason_code:?}{}",
            reason_string
                .as_deref()
                .map(|r| format!(" ({r})"))
                .unwrap_or_default()
        ),
        ConnectionError::MqttState(StateError::ConnectionAborted) => {
            format!("broker {broker} closed the connection")
        }
        ConnectionError::MqttState(StateError::AwaitPingResp) => {
            format!("broker {broker} stopped answering (no reply to the keep-alive ping)")
        }
        other => format!("broker {broker}: {other}"),
    }
}

/// Whether a TLS handshake failed because the peer does not speak TLS: it hung up on the
/// ClientHello (a plain MQTT listener takes it for a malformed packet) or answered with what
/// is no TLS record. A certificate the client refuses is something else (`ca_file`).
fn not_tls(e: &rumqttc::TlsError) -> bool {
    use std::io::ErrorKind;
    let rumqttc::TlsError::Io(io) = e else {
        return false;
    };
    match io.kind() {
        ErrorKind::ConnectionReset | ErrorKind::ConnectionAborted | ErrorKind::UnexpectedEof => {
            true
        }
        _ => matches!(
            io.get_ref()
                .and_then(|inner| inner.downcast_ref::<rustls::Error>()),
            Some(rustls::Error::InvalidMessage(_))
        ),
    }
}
