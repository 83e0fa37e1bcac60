//! Who may use the page and API (`service::authority` decides who may act on a rig; this is
//! its word over HTTP). Changing anything (every request but a `GET`: forcing, driving the
//! simulated field) needs the run's key (`authority::RunKey`: in the link the run prints,
//! and beside its socket, readable by whoever may use the socket) or the control token. Looking
//! (`GET`) is open on a loopback address without a token; with a token (`ui_token` /
//! `RIGSCRIPT_UI_TOKEN`, required on any other address) every request but the page's own files
//! carries `Authorization: Bearer TOKEN` (the run's key counts as the control token). The read
//! token (`ui_read_token` / `RIGSCRIPT_UI_READ_TOKEN`) may only look. Tokens are checked alike
//! wherever they come from (`authority::check_token`), compared in constant time and never
//! logged (`config::Secret`).

use super::request::HttpRequest;
use super::response::Response;
use crate::config::Secret;
use crate::service::authority::{self, RunKey};

/// The environment variable that gives the control token (it wins over rig.toml's).
pub const TOKEN_ENV: &str = "RIGSCRIPT_UI_TOKEN";

/// The environment variable that gives the read token.
pub const READ_TOKEN_ENV: &str = "RIGSCRIPT_UI_READ_TOKEN";

/// The page's own files, served to anyone: they hold no state, and the page asks for the
/// token itself.
const OPEN: &[&str] = &["/", "/uplot.js", "/uplot.css"];

/// The tokens of a served page.
#[derive(Debug, Clone, Default)]
pub struct Tokens {
    control: Option<Secret>,
    read: Option<Secret>,
    key: Option<RunKey>,
}

/// A token from the environment that is not one.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{name} {reason}")]
pub struct BadEnvToken {
    /// The variable.
    pub name: &'static str,
    /// Why, without the token.
    pub reason: authority::BadToken,
}

/// By what right a request was let through.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Right {
    /// None asked: looking on a loopback address without a token.
    Open,
    /// The run's key.
    Key,
    /// The control token.
    Control,
    /// The read token.
    Read,
}

impl Right {
    /// Who acted, for the log: `the web page with the run's key (127.0.0.1:40000)`.
    pub fn by(self, peer: Option<std::net::SocketAddr>) -> String {
        let with = match self {
            Right::Open => "the web page",
            Right::Key => "the web page with the run's key",
            Right::Control => "the web page with ui_token",
            Right::Read => "the web page with ui_read_token",
        };
        match peer {
            Some(p) => format!("{with} ({p})"),
            None => with.to_string(),
        }
    }
}

impl Tokens {
    /// rig.toml's tokens (checked as rig.toml was read), each replaced by its environment
    /// variable where that is set, checked the same way; and the run's key.
    pub fn from(
        control: Option<&Secret>,
        read: Option<&Secret>,
        key: Option<RunKey>,
    ) -> Result<Self, BadEnvToken> {
        let env = |name: &'static str| match std::env::var(name) {
            Ok(v) if !v.is_empty() => authority::check_token(&v)
                .map(|()| Some(Secret::new(v)))
                .map_err(|reason| BadEnvToken { name, reason }),
            _ => Ok(None),
        };
        Ok(Self {
            control: env(TOKEN_ENV)?.or_else(|| control.cloned()),
            read: env(READ_TOKEN_ENV)?.or_else(|| read.cloned()),
            key,
        })
    }

    /// Whether there is a control token.
    pub fn controlled(&self) -> bool {
        self.control.is_some()
    }

    /// Whether requests must carry a token.
    pub fn required(&self) -> bool {
        self.control.is_some() || self.read.is_some()
    }

    /// Lets `request` through, with the right it came by, or says why not: 401 without a
    /// token or with a wrong one (a change without the run's key or the control token), 403 a
    /// read token on anything but a `GET`.
    pub fn check(&self, request: &HttpRequest) -> Result<Right, Response> {
        let looks = request.method == "GET";
        if looks && (!self.required() || OPEN.contains(&request.path.as_str())) {
            return Ok(Right::Open);
        }
        let given = request
            .header("authorization")
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(str::trim);
        let Some(given) = given else {
            return Err(Response::error(
                401,
                if looks {
                    "this page asks for a token: send Authorization: Bearer TOKEN (ui_token or \
                     ui_read_token in rig.toml, RIGSCRIPT_UI_TOKEN or RIGSCRIPT_UI_READ_TOKEN)"
                        .to_string()
                } else {
                    format!(
                        "{} {} changes the rig: send Authorization: Bearer KEY with the run's \
                         key (the link `rigscript run` printed, ui: http://...#key=KEY, or the \
                         file RIG.key beside the rig's control socket) or the ui_token",
                        request.method, request.path
                    )
                },
            ));
        };
        let matches = |s: &Option<Secret>| {
            s.as_ref()
                .is_some_and(|s| authority::same_secret(s.expose(), given))
        };
        // Each compared whatever the others gave: the time does not tell which one matched.
        let (control, read) = (matches(&self.control), matches(&self.read));
        let key = self
            .key
            .as_ref()
            .is_some_and(|k| authority::same_secret(k.expose(), given));
        if key {
            Ok(Right::Key)
        } else if control {
            Ok(Right::Control)
        } else if read && looks {
            Ok(Right::Read)
        } else if read {
            Err(Response::error(
                403,
                format!(
                    "the read token may only look (GET); {} {} needs the control token",
                    request.method, request.path
                ),
            ))
        } else {
            Err(Response::error(401, "the token is not this page's"))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(method: &str, path: &str, auth: Option<&str>) -> HttpRequest {
        HttpRequest {
            method: method.into(),
            path: path.into(),
            headers: auth
                .map(|a| vec![("authorization".to_string(), a.to_string())])
                .unwrap_or_default(),
            body: Vec::new(),
        }
    }

    fn status(t: &Tokens, method: &str, path: &str, auth: Option<&str>) -> u16 {
        match t.check(&request(method, path, auth)) {
            Ok(_) => 200,
            Err(r) => r.status,
        }
    }

    #[test]
    fn the_control_token_does_everything_the_read_token_only_looks() {
        let t = Tokens {
            control: Some(Secret::new("c0ntrol".into())),
            read: Some(Secret::new("l00k".into())),
            key: None,
        };
        assert_eq!(status(&t, "GET", "/", None), 200, "the page asks itself");
        assert_eq!(status(&t, "GET", "/api/state", None), 401);
        assert_eq!(status(&t, "GET", "/api/state", Some("Bearer nope")), 401);
        assert_eq!(status(&t, "GET", "/api/state", Some("Basic c0ntrol")), 401);
        assert_eq!(status(&t, "GET", "/api/state", Some("Bearer c0ntro")), 401);
        assert_eq!(
            status(&t, "GET", "/api/state", Some("Bearer c0ntroll")),
            401
        );
        assert_eq!(status(&t, "GET", "/api/state", Some("Bearer l00k")), 200);
        assert_eq!(status(&t, "POST", "/api/sim", Some("Bearer l00k")), 403);
        assert_eq!(
            status(&t, "DELETE", "/api/force/io.DO3", Some("Bearer l00k")),
            403
        );
        assert_eq!(status(&t, "POST", "/api/sim", Some("Bearer c0ntrol")), 200);
        assert_eq!(
            status(&t, "POST", "/", None),
            401,
            "only a GET of the page is open"
        );
    }

    #[test]
    fn without_a_token_anyone_looks_and_only_the_run_s_key_changes() {
        let key = RunKey::generate().unwrap();
        let bearer = format!("Bearer {}", key.expose());
        let t = Tokens {
            key: Some(key.clone()),
            ..Tokens::default()
        };
        assert_eq!(status(&t, "GET", "/api/state", None), 200);
        assert_eq!(status(&t, "POST", "/api/sim", None), 401);
        assert_eq!(
            status(&t, "POST", "/api/sim", Some("Bearer guess-guess")),
            401
        );
        assert_eq!(status(&t, "DELETE", "/api/force/io.DO3", None), 401);
        assert_eq!(status(&t, "POST", "/api/sim", Some(&bearer)), 200);
        assert_eq!(
            t.check(&request("POST", "/api/force", Some(&bearer))),
            Ok(Right::Key)
        );
        let with_token = Tokens {
            control: Some(Secret::new("c0ntrol-token".into())),
            ..t
        };
        assert_eq!(status(&with_token, "GET", "/api/state", Some(&bearer)), 200);
        assert_eq!(
            with_token.check(&request("POST", "/api/sim", Some("Bearer c0ntrol-token"))),
            Ok(Right::Control)
        );
    }

    #[test]
    fn debug_forms_hide_the_tokens() {
        let t = Tokens {
            control: Some(Secret::new("s3cret".into())),
            read: None,
            key: None,
        };
        assert!(!format!("{t:?}").contains("s3cret"));
    }
}
