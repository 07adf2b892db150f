//! The machine a time was measured on, written beside every time that `ivp bench` and `ivp eval`
//! report. The same build runs the network about twice as fast where the CPU has AVX-512 (gemm,
//! under the convolutions, picks its widest kernels at run time): a 1080p frame took 88-92 ms on
//! one 2-core machine and 192-208 ms on another without AVX-512 (PERFORMANCE.md), so a time means
//! little without the machine it was measured on.

use std::fmt;

use serde::Serialize;

/// What the speed of a run depends on, as far as the program can tell.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Machine {
    /// The CPU's model name (`/proc/cpuinfo` on Linux), or `unknown`.
    pub cpu: String,
    /// The widest vector instructions this CPU offers the matrix products: `avx512`, `avx2`,
    /// `neon`, or `baseline` (none of those).
    pub vectors: &'static str,
}

impl Machine {
    pub fn this() -> Self {
        Self { cpu: cpu_model(), vectors: widest_vectors() }
    }
}

/// `AMD EPYC (avx2)`, for tables and logs.
impl fmt::Display for Machine {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({})", self.cpu, self.vectors)
    }
}

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|info| model_name(&info))
        .unwrap_or_else(|| "unknown".to_string())
}

/// The first `model name` of a `/proc/cpuinfo` text.
fn model_name(cpuinfo: &str) -> Option<String> {
    cpuinfo.lines().find_map(|line| {
        let (key, value) = line.split_once(':')?;
        (key.trim() == "model name" && !value.trim().is_empty()).then(|| value.trim().to_string())
    })
}

#[cfg(target_arch = "x86_64")]
fn widest_vectors() -> &'static str {
    if std::arch::is_x86_feature_detected!("avx512f") {
        "avx512"
    } else if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        "avx2"
    } else {
        "baseline"
    }
}

#[cfg(target_arch = "aarch64")]
fn widest_vectors() -> &'static str {
    "neon"
}

#[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
fn widest_vectors() -> &'static str {
    "baseline"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_model_name_is_the_first_one_given() {
        let info = "processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC 7B13\nflags\t\t: fpu\n\
                    processor\t: 1\nmodel name\t: other\n";
        assert_eq!(model_name(info).as_deref(), Some("AMD EPYC 7B13"));
        assert_eq!(model_name("processor\t: 0\nmodel name\t:   \n"), None);
        assert_eq!(model_name(""), None);
    }

    #[test]
    fn this_machine_names_its_cpu_and_vectors() {
        let machine = Machine::this();
        assert!(["avx512", "avx2", "neon", "baseline"].contains(&machine.vectors), "{machine:?}");
        assert!(!machine.cpu.is_empty());
        // The build targets x86-64-v3 (.cargo/config.toml): AVX2 at least.
        #[cfg(target_arch = "x86_64")]
        assert!(["avx512", "avx2"].contains(&machine.vectors), "{machine:?}");
        assert_eq!(machine.to_string(), format!("{} ({})", machine.cpu, machine.vectors));
    }
}
