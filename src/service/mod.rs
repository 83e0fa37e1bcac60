//! Services around a run, off the scan loop: the systemd notification protocol (readiness,
//! status, the service watchdog fed from the scan loop) and the control socket through which
//! `rigscript status`, `list` and `stop` see and drive a running rig, and the web page and
//! HTTP API (`run --ui`) that do the same from a browser, and the MQTT client (`[mqtt]`) that
//! tells a broker and takes commands from it.

pub mod authority;
pub mod control_client;
pub mod control_protocol;
pub mod control_socket;
pub mod http;
pub mod mqtt;
pub mod notify;
pub mod reload;
pub mod rig_dir;
pub mod serving;
