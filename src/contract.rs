//! The contract: what every answer of the crate must be, checked by the
//! tests against a brute-force oracle and against ground truths. Section
//! numbers (S0 to S10) are what the rest of the documentation cites.
#![doc = include_str!("../docs/contract.md")]
