//! Rhai scripts: the sandboxed engine, the script API bound to the runtime, running a script
//! as the scan loop's program, static checks (`rigscript check`) and scenario tests
//! (`rigscript test`). Nothing below this layer knows Rhai.

pub mod api;
pub mod builder;
pub mod check;
pub mod engine;
pub mod error;
mod fn_scope;
#[cfg(test)]
mod invariant_tests;
pub mod lint;
pub mod point_names;
pub mod program;
pub mod reads;
#[cfg(test)]
mod reload_tests;
pub mod rig;
pub mod scenario;
pub mod stack;
pub mod test_budget;
pub mod values;
pub mod watched;
#[cfg(test)]
mod watched_tests;
