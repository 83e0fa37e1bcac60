//! Who may use the page and API: nobody is asked on a loopback address without a token; with
//! a token (`ui_token` / `RIGSCRIPT_UI_TOKEN`, required on any other address) every request
//! but the page's own files carries `Authorization: Bearer TOKEN`. The control token may do
//! everything, the read token (`ui_read_token` / `RIGSCRIPT_UI_READ_TOKEN`) only look (`GET`).
//! Tokens are compared in constant time and never logged (`config::Secret`).

use super::request::HttpRequest;
use super::response::Response;
use crate::config::Secret;

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
}

impl Tokens {
    /// rig.toml's tokens, each replaced by its environment variable where that is set.
    pub fn from(control: Option<&Secret>, read: Option<&Secret>) -> Self {
        let env = |name: &str| {
            std::env::var(name)
                .ok()
                .filter(|v| !v.is_empty())
                .map(Secret::new)
        };
        Self {
            control: env(TOKEN_ENV).or_else(|| control.cloned()),
            read: env(READ_TOKEN_ENV).or_else(|| read.cloned()),
        }
    }

    /// Whether there is a control token.
    pub fn controlled(&self) -> bool {
        self.control.is_some()
    }

    /// Whether requests must carry a token.
    pub fn required(&self) -> bool {
        self.control.is_some() || self.read.is_some()
    }

    /// Lets `request` through, or says why not: 401 without a token or with a wrong one, 403
    /// a read token on anything but a `GET`.
    pub fn check(&self, request: &HttpRequest) -> Result<(), Response> {
        if !self.required() || (request.method == "GET" && OPEN.contains(&request.path.as_str())) {
            return Ok(());
        }
        let given = request
            .header("authorization")
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(str::trim);
        let Some(given) = given else {
            return Err(Response::error(
                401,
                "this page asks for a token: send Authorization: Bearer TOKEN (ui_token or \
                 ui_read_token in rig.toml, RIGSCRIPT_UI_TOKEN or RIGSCRIPT_UI_READ_TOKEN)",
            ));
        };
        let matches = |s: &Option<Secret>| s.as_ref().is_some_and(|s| same(s.expose(), given));
        // Both compared whatever the first gave: the time does not tell which one matched.
        let (control, read) = (matches(&self.control), matches(&self.read));
        if control || (read && request.method == "GET") {
            Ok(())
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

/// Whether `a` and `b` are the same, in a time that depends only on their lengths.
fn same(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    let mut diff = a.len() ^ b.len();
    for i in 0..a.len().max(b.len()) {
        let x = a.get(i).copied().unwrap_or(0);
        let y = b.get(i).copied().unwrap_or(0);
        diff |= usize::from(x ^ y);
    }
    std::hint::black_box(diff) == 0
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
            Ok(()) => 200,
            Err(r) => r.status,
        }
    }

    #[test]
    fn the_control_token_does_everything_the_read_token_only_looks() {
        let t = Tokens {
            control: Some(Secret::new("c0ntrol".into())),
            read: Some(Secret::new("l00k".into())),
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
        assert_eq!(status(&Tokens::default(), "POST", "/api/sim", None), 200);
    }

    #[test]
    fn tokens_compare_by_every_byte_and_their_debug_form_hides_them() {
        assert!(same("abc", "abc"));
        assert!(!same("abc", "abd") && !same("abc", "ab") && !same("", "a"));
        let t = Tokens {
            control: Some(Secret::new("s3cret".into())),
            read: None,
        };
        assert!(!format!("{t:?}").contains("s3cret"));
    }
}
