//! onnxruntime beside the project's engines in `bino bench`: a long-lived
//! `python -m bino_train.ort_bench --serve` process, asked for one timed run at a time, so its
//! runs interleave with tract's and the int8 engine's and all see the same machine.
//!
//! It holds two one-thread sessions of the float encoder: the float graph (`f32`) and its
//! dynamic int8 quantisation (`int8`: int8 weights, activations quantised at run time).

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

use anyhow::{bail, Context, Result};

use crate::io::train_python::{pgm, tempdir, TrainPython};

/// One of the server's sessions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OrtSession {
    /// The float graph.
    F32,
    /// `quantize_dynamic` of it (int8 weights, dynamic activations).
    Int8Dynamic,
}

impl OrtSession {
    fn request(self) -> &'static str {
        match self {
            Self::F32 => "f32",
            Self::Int8Dynamic => "int8",
        }
    }
}

/// The running server; dropping it closes its stdin and waits for it.
pub struct OrtServer {
    child: Child,
    requests: Option<ChildStdin>,
    replies: BufReader<ChildStdout>,
    dir: PathBuf,
}

impl OrtServer {
    /// Starts the server on `onnx` and the 8-bit gray band, and waits until both sessions
    /// are loaded and warmed up.
    pub fn start(env: &TrainPython, onnx: &Path, band: &[u8], width: usize, height: usize) -> Result<Self> {
        let dir = tempdir("ort")?;
        let band_path = dir.join("band.pgm");
        std::fs::write(&band_path, pgm(band, width, height))
            .with_context(|| format!("cannot write {}", band_path.display()))?;
        let onnx = std::fs::canonicalize(onnx).with_context(|| format!("{}: cannot open", onnx.display()))?;
        let mut child = Command::new(&env.python)
            .args(["-W", "ignore", "-m", "bino_train.ort_bench", "--serve", "--onnx"])
            .arg(&onnx)
            .arg("--band")
            .arg(&band_path)
            .current_dir(&env.train_dir)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .with_context(|| format!("cannot start {}", env.python.display()))?;
        let (Some(requests), Some(replies)) = (child.stdin.take(), child.stdout.take()) else {
            bail!("onnxruntime server: no pipes");
        };
        let mut server = Self {
            child,
            requests: Some(requests),
            replies: BufReader::new(replies),
            dir,
        };
        let ready = server.reply()?;
        if ready != "ready" {
            bail!("onnxruntime server: expected `ready`, got {ready:?}");
        }
        Ok(server)
    }

    /// One timed run of `session`, in seconds, as the server measured it.
    pub fn time(&mut self, session: OrtSession) -> Result<f64> {
        let requests = self.requests.as_mut().context("onnxruntime server: closed")?;
        writeln!(requests, "{}", session.request()).context("onnxruntime server: cannot send")?;
        requests.flush().context("onnxruntime server: cannot send")?;
        let reply = self.reply()?;
        reply
            .parse::<f64>()
            .with_context(|| format!("onnxruntime server: expected seconds, got {reply:?}"))
    }

    fn reply(&mut self) -> Result<String> {
        let mut line = String::new();
        let read = self
            .replies
            .read_line(&mut line)
            .context("onnxruntime server: cannot read")?;
        if read == 0 {
            bail!(
                "onnxruntime server (python -m bino_train.ort_bench) exited early: see its error \
                 above, or pass --no-onnxruntime"
            );
        }
        Ok(line.trim().to_string())
    }
}

impl Drop for OrtServer {
    fn drop(&mut self) {
        // Closing stdin ends the server's request loop.
        drop(self.requests.take());
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_server_times_both_sessions_when_python_is_there() {
        let Ok(env) = TrainPython::locate("onnxruntime", "--no-onnxruntime") else {
            crate::test_inputs::skip("the Python environment (scripts/setup.sh)");
            return;
        };
        let onnx = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../weights/bino_encoder.onnx"));
        let (width, height) = (64, 48);
        let band: Vec<u8> = (0..width * height).map(|i| (i * 37 % 251) as u8).collect();
        let mut server = OrtServer::start(&env, onnx, &band, width, height).unwrap();
        for session in [OrtSession::F32, OrtSession::Int8Dynamic, OrtSession::F32] {
            let seconds = server.time(session).unwrap();
            assert!(seconds > 0.0 && seconds < 60.0, "{session:?}: {seconds}");
        }
    }

    #[test]
    fn a_missing_model_is_named_before_python_starts() {
        let env = TrainPython {
            python: PathBuf::from("/nonexistent/python"),
            train_dir: PathBuf::from("."),
        };
        let err = OrtServer::start(&env, Path::new("no/such.onnx"), &[0; 4], 2, 2)
            .err()
            .unwrap();
        assert!(format!("{err:#}").starts_with("no/such.onnx: cannot open"), "{err:#}");
    }
}
