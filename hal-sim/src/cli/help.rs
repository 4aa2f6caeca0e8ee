//! Help text wrapped to 100 columns. clap wraps only with its `wrap_help` feature (and the
//! `terminal_size` dependency that comes with it), so the doc comments' paragraphs would
//! print as single lines of several hundred characters; this rewraps every `about` and
//! option help of a command tree before parsing, and puts each option's help under it.

use clap::Command;

/// The widest help line, in characters.
pub const WIDTH: usize = 100;
/// A subcommand's `about` also stands in its parent's list after the name (≤ 24 columns).
const ABOUT_WIDTH: usize = WIDTH - 24;
/// Option help stands 10 columns in, with `[default: …]` or `[possible values: …]` after
/// its last line in the short help.
const ARG_WIDTH: usize = WIDTH - 10;

/// Greedy word wrap of every line of `text` to `width` characters; a line's leading spaces
/// (and a `- ` list marker) indent its continuation lines. A single word longer than the
/// width stays whole.
pub fn wrap(text: &str, width: usize) -> String {
    let mut out = String::with_capacity(text.len() + text.len() / width.max(1));
    for (k, line) in text.split('\n').enumerate() {
        if k > 0 {
            out.push('\n');
        }
        let body = line.trim_start();
        let lead = line.len() - body.len();
        let hang = lead + if body.starts_with("- ") { 2 } else { 0 };
        let mut col = 0;
        for (i, word) in body.split(' ').filter(|w| !w.is_empty()).enumerate() {
            let n = word.chars().count();
            if i == 0 {
                out.push_str(&line[..lead]);
                col = lead;
            } else if col + 1 + n > width {
                out.push('\n');
                out.extend(std::iter::repeat_n(' ', hang));
                col = hang;
            } else {
                out.push(' ');
                col += 1;
            }
            out.push_str(word);
            col += n;
        }
    }
    out
}

/// `a` with its help wrapped, the defaults, aliases and possible values clap would append
/// to it unwrapped written into it (and hidden from clap).
fn wrapped_arg(a: clap::Arg) -> clap::Arg {
    let Some(help) = a.get_help().map(ToString::to_string) else {
        return a;
    };
    let mut tags = Vec::new();
    let defaults: Vec<String> = a
        .get_default_values()
        .iter()
        .map(|v| v.to_string_lossy().into_owned())
        .collect();
    let show_default =
        a.get_action().takes_values() && !a.is_hide_default_value_set() && !defaults.is_empty();
    if show_default {
        tags.push(format!("[default: {}]", defaults.join(", ")));
    }
    let aliases: Vec<String> = a
        .get_visible_aliases()
        .unwrap_or_default()
        .iter()
        .map(|s| format!("--{s}"))
        .collect();
    if !aliases.is_empty() {
        tags.push(format!("[alias: {}]", aliases.join(", ")));
    }
    let values: Vec<clap::builder::PossibleValue> = if a.is_hide_possible_values_set() {
        Vec::new()
    } else {
        a.get_possible_values()
            .into_iter()
            .filter(|v| !v.is_hide_set())
            .collect()
    };
    let names: Vec<&str> = values
        .iter()
        .map(clap::builder::PossibleValue::get_name)
        .collect();
    let short_values = if names.is_empty() || !a.get_action().takes_values() {
        String::new()
    } else {
        format!(" [possible values: {}]", names.join(", "))
    };
    let tags = if tags.is_empty() {
        String::new()
    } else {
        format!(" {}", tags.join(" "))
    };
    let long = a
        .get_long_help()
        .map_or_else(|| help.clone(), ToString::to_string);
    let mut long = format!("{long}{tags}");
    if values.iter().any(|v| v.get_help().is_some()) && a.get_action().takes_values() {
        long.push_str("\n\nPossible values:");
        for v in &values {
            match v.get_help() {
                Some(h) => long.push_str(&format!("\n- {}: {h}", v.get_name())),
                None => long.push_str(&format!("\n- {}", v.get_name())),
            }
        }
    } else {
        long.push_str(&short_values);
    }
    let all_aliases: Vec<String> = a
        .get_all_aliases()
        .unwrap_or_default()
        .iter()
        .map(ToString::to_string)
        .collect();
    let takes_values = a.get_action().takes_values();
    let a = a
        .alias(None::<&str>)
        .aliases(all_aliases)
        .help(wrap(&format!("{help}{tags}{short_values}"), ARG_WIDTH))
        .long_help(wrap(&long, ARG_WIDTH));
    if takes_values {
        a.hide_default_value(true).hide_possible_values(true)
    } else {
        a
    }
}

/// `cmd` and all its subcommands with their help wrapped (see the module's text). The
/// top level keeps its list of commands one to a line with their `about` beside it.
pub fn wrapped(cmd: Command) -> Command {
    wrap_tree(cmd, true)
}

fn wrap_tree(cmd: Command, top: bool) -> Command {
    let about = cmd.get_about().map(|a| wrap(&a.to_string(), ABOUT_WIDTH));
    let long_about = cmd.get_long_about().map(|a| wrap(&a.to_string(), WIDTH));
    let mut cmd = cmd.next_line_help(!top).mut_args(wrapped_arg);
    if let Some(a) = about {
        cmd = cmd.about(a);
    }
    if let Some(a) = long_about {
        cmd = cmd.long_about(a);
    }
    cmd.mut_subcommands(|c| wrap_tree(c, false))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_are_wrapped_at_word_boundaries_and_lists_hang() {
        let text = "one two three four five six\n- alpha beta gamma delta";
        let w = wrap(text, 12);
        assert_eq!(
            w,
            "one two\nthree four\nfive six\n- alpha beta\n  gamma\n  delta"
        );
        assert!(w.lines().all(|l| l.chars().count() <= 12));
        // A word longer than the width stays whole; empty lines (paragraphs) stay.
        assert_eq!(wrap("a verylongword b\n\nc", 5), "a\nverylongword\nb\n\nc");
    }
}
