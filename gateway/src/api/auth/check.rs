//! The API tokens' checks: at start, every token of `[http]` read from its file or variable as
//! `run` reads it (at least 16 visible characters, no two alike); through the REST API, each
//! token file confined to `[gateway] config_dirs`.

use crate::config::check::Check;
use crate::config::{ConfigIssue, Cx, HttpConfig, TokenSource};
use crate::plant::check::{ApiChange, Start};

use super::{Auth, TokenError};

/// The tokens of `[http]`: the default one and the named ones.
pub(crate) struct ApiTokens;

impl Check<Start<'_>> for ApiTokens {
    fn check(&self, start: &Start<'_>, cx: &mut Cx) {
        cx.issues.extend(all_token_issues(
            &start.config.http,
            |name| std::env::var(name).ok(),
            &|key| start.refused(key),
        ));
    }
}

impl Check<ApiChange<'_>> for ApiTokens {
    fn check(&self, change: &ApiChange<'_>, cx: &mut Cx) {
        let (new, old) = (&change.new.http, &change.in_force.http);
        let default = (new.token_file.as_deref(), old.token_file.as_deref());
        change.config_file(cx, "http.token_file", default.0, default.1);
        for (name, token) in &new.tokens {
            let old = old.tokens.get(name).and_then(|t| t.token_file.as_deref());
            let key = format!("http.tokens.{name}.token_file");
            change.config_file(cx, &key, token.token_file.as_deref(), old);
        }
    }
}

/// The token of `[http]` as run reads it, with `env` for the process environment: the first
/// problem only (what `run` stops on); [`all_token_issues`] finds every one.
pub(crate) fn token_issues(
    http: &HttpConfig,
    env: impl Fn(&str) -> Option<String>,
) -> Vec<ConfigIssue> {
    match Auth::from_config_with(http, env) {
        Ok(_) => Vec::new(),
        Err(e) => vec![token_issue(http, &e)],
    }
}

/// Every token of `[http]` read as run reads it, each on its own, so that every file or
/// variable that cannot be had is an issue at its key; then, when all could be read, whether
/// two are alike. A token whose key `refused` names (a file outside its directories) is not read.
pub(crate) fn all_token_issues(
    http: &HttpConfig,
    env: impl Fn(&str) -> Option<String>,
    refused: &dyn Fn(&str) -> bool,
) -> Vec<ConfigIssue> {
    let key = |source: &TokenSource| match source {
        TokenSource::File(_) => "token_file",
        TokenSource::Env(_) => "token_env",
    };
    let mut issues = Vec::new();
    let mut skipped = false;
    // One source at a time, as the default token of an otherwise empty section.
    let alone = |source: TokenSource| HttpConfig {
        token_file: match &source {
            TokenSource::File(p) => Some(p.clone()),
            TokenSource::Env(_) => None,
        },
        token_env: match source {
            TokenSource::Env(n) => Some(n),
            TokenSource::File(_) => None,
        },
        ..HttpConfig::default()
    };
    let sources = http.token_source().map(|s| (None, s)).into_iter().chain(
        http.tokens
            .iter()
            .filter_map(|(name, t)| Some((Some(name.as_str()), t.source()?))),
    );
    for (name, source) in sources {
        let path = match name {
            None => format!("http.{}", key(&source)),
            Some(name) => format!("http.tokens.{name}.{}", key(&source)),
        };
        if refused(&path) {
            skipped = true;
            continue;
        }
        if let Err(e) = Auth::from_config_with(&alone(source), &env) {
            issues.push(ConfigIssue {
                path,
                message: match name {
                    None => e.to_string(),
                    Some(name) => format!("token {name}: {e}"),
                },
            });
        }
    }
    if issues.is_empty() && !skipped {
        issues.extend(token_issues(http, env));
    }
    issues
}

/// A token error as an issue at the key that names the token's source.
pub(crate) fn token_issue(http: &HttpConfig, e: &TokenError) -> ConfigIssue {
    let path = match e {
        TokenError::Named { name, .. } => {
            let key = match http.tokens.get(name).and_then(|t| t.source()) {
                Some(TokenSource::Env(_)) => "token_env",
                _ => "token_file",
            };
            format!("http.tokens.{name}.{key}")
        }
        TokenError::Duplicate(..) => "http.tokens".to_owned(),
        _ => match http.token_source() {
            Some(TokenSource::Env(_)) => "http.token_env".to_owned(),
            _ => "http.token_file".to_owned(),
        },
    };
    ConfigIssue {
        path,
        message: e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_named_token_that_cannot_be_read_is_an_issue_at_its_key() {
        let http = crate::plant::parse(
            "[http.tokens.ops]\nrole = \"operator\"\ntoken_env = \"OPS\"\n\
             [http.tokens.eng]\nrole = \"admin\"\ntoken_file = \"/nonexistent/eng.token\"\n",
        )
        .expect("parses")
        .http;
        let issues = token_issues(&http, |_| Some("ops-token-0123456789".to_owned()));
        assert_eq!(issues.len(), 1, "{issues:?}");
        assert_eq!(issues[0].path, "http.tokens.eng.token_file");
        assert!(
            issues[0].message.contains("/nonexistent/eng.token"),
            "{}",
            issues[0].message
        );
        let issues = token_issues(&http, |_| None);
        assert_eq!(issues[0].path, "http.tokens.eng.token_file");
    }

    #[test]
    fn every_token_problem_is_reported_at_its_key() {
        let http = crate::plant::parse(
            "[http]\ntoken_file = \"/nonexistent/admin.token\"\n\
             [http.tokens.ops]\nrole = \"operator\"\ntoken_env = \"OPS\"\n\
             [http.tokens.hmi]\nrole = \"viewer\"\ntoken_env = \"HMI\"\n",
        )
        .expect("parses")
        .http;
        let issues = all_token_issues(&http, |_| None, &|_| false);
        let paths: Vec<&str> = issues.iter().map(|i| i.path.as_str()).collect();
        assert_eq!(
            paths,
            [
                "http.token_file",
                "http.tokens.hmi.token_env",
                "http.tokens.ops.token_env"
            ],
            "{issues:#?}"
        );
        assert_eq!(
            issues[2].message,
            "token ops: the API token variable OPS is not set"
        );
        // All readable, two alike: one issue at http.tokens.
        let http = crate::plant::parse(
            "[http]\ntoken_env = \"A\"\n[http.tokens.ops]\nrole = \"operator\"\ntoken_env = \"B\"\n",
        )
        .expect("parses")
        .http;
        let issues = all_token_issues(&http, |_| Some("same-token-0123456789".into()), &|_| false);
        assert_eq!(issues.len(), 1, "{issues:#?}");
        assert_eq!(issues[0].path, "http.tokens");
    }
}
