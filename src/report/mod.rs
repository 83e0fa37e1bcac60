//! Reports for CI: runs and scenario tests as JUnit XML (`--junit FILE`), which Jenkins and
//! GitLab show as test results.

pub mod junit;
pub mod measurements;
