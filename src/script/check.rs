//! `rigscript check`: static checks of a script.
