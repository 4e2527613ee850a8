//! The command line: parts to run and options.
use std::path::PathBuf;

/// The parts `all` (and no part named) runs; `variants` runs only when named.
const ALL_PARTS: [&str; 6] = [
    "grid",
    "beyond",
    "appendix",
    "scans",
    "scans-one-start",
    "figures",
];

pub struct Options {
    pub parts: Vec<String>,
    pub instances: usize,
    pub threads: usize,
    pub out: PathBuf,
    pub figures: PathBuf,
    pub doc: Option<PathBuf>,
    pub data: PathBuf,
    /// Scans: only the method with this CSV key.
    pub method: Option<String>,
    /// The command line, recorded in the document.
    pub command: String,
}

pub fn parse_options() -> Result<Options, String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut options = Options {
        parts: Vec::new(),
        instances: 100,
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        out: PathBuf::from("results"),
        figures: PathBuf::from("docs/figures"),
        doc: Some(PathBuf::from("docs/results.md")),
        data: std::env::var_os("SIE_DATA_DIR").map_or_else(|| PathBuf::from("../shared/data"), PathBuf::from),
        method: None,
        command: format!(
            "cargo run --release --example experiments --{}",
            args.iter().map(|a| format!(" {a}")).collect::<String>()
        ),
    };
    let mut it = args.into_iter();
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().ok_or_else(|| format!("{name} needs a value"));
        match arg.as_str() {
            "--instances" => {
                options.instances = value("--instances")?
                    .parse()
                    .map_err(|_| "--instances takes a positive integer".to_string())?
            }
            "--threads" => {
                options.threads = value("--threads")?
                    .parse()
                    .map_err(|_| "--threads takes a positive integer".to_string())?
            }
            "--out" => options.out = value("--out")?.into(),
            "--figures" => options.figures = value("--figures")?.into(),
            "--doc" => {
                let v = value("--doc")?;
                options.doc = (v != "-").then(|| v.into());
            }
            "--data" => options.data = value("--data")?.into(),
            "--method" => options.method = Some(value("--method")?),
            "grid" | "beyond" | "appendix" | "scans" | "scans-one-start" | "figures" | "variants" => {
                options.parts.push(arg)
            }
            "all" => options.parts.extend(ALL_PARTS.map(String::from)),
            "-h" | "--help" => {
                println!(
                    "{}",
                    include_str!("../experiments.rs")
                        .lines()
                        .take(19)
                        .map(|l| l.trim_start_matches("//!"))
                        .collect::<Vec<_>>()
                        .join("\n")
                );
                std::process::exit(0);
            }
            other => return Err(format!("unknown argument {other:?} (try --help)")),
        }
    }
    if options.parts.is_empty() {
        options.parts.extend(ALL_PARTS.map(String::from));
    }
    if options.instances == 0 || options.threads == 0 {
        return Err("--instances and --threads must be >= 1".into());
    }
    Ok(options)
}
