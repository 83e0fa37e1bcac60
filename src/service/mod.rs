//! Running under a service manager: the systemd notification protocol (readiness, status, the
//! service watchdog fed from the scan loop).

pub mod notify;
