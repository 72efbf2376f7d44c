//! placeholder (helper implements)
