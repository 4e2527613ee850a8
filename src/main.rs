//! `sie` command-line tool (see `sie --help`).
fn main() {
    eprintln!("sie: the command-line tool is not built yet");
    std::process::exit(2);
}
