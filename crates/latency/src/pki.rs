//! Certificates for the control room's TLS, made with the `openssl` command in one
//! folder: certificate authorities and the certificates they sign (EC P-256, valid
//! two days), for a run of `jetbench latency --control-room` and for the tests that
//! stand a control room up. Each step's error says what failed.

use std::path::{Path, PathBuf};

/// The `openssl` command, run in a folder where the keys and certificates go.
pub struct Openssl {
    dir: PathBuf,
}

/// A new key on P-256, unencrypted.
const EC_KEY: [&str; 5] = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"];

impl Openssl {
    /// Works in `dir` (created if missing).
    pub fn in_dir(dir: &Path) -> Result<Openssl, String> {
        std::fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
        Ok(Openssl { dir: dir.to_path_buf() })
    }

    fn run(&self, args: &[&str]) -> Result<(), String> {
        let out = std::process::Command::new("openssl")
            .current_dir(&self.dir)
            .args(args)
            .output()
            .map_err(|e| format!("cannot run openssl (install it, e.g. apt-get install openssl): {e}"))?;
        if out.status.success() {
            Ok(())
        } else {
            Err(format!("openssl {} failed: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim()))
        }
    }

    /// A self-signed certificate authority: `NAME.key` and `NAME.crt`, common name `cn`.
    pub fn ca(&self, name: &str, cn: &str) -> Result<(), String> {
        let (key, crt, subject) = (format!("{name}.key"), format!("{name}.crt"), format!("/CN={cn}"));
        let mut args = vec!["req", "-x509"];
        args.extend(EC_KEY);
        args.extend(["-keyout", &key, "-out", &crt, "-days", "2", "-subj", &subject]);
        args.extend([
            "-addext",
            "basicConstraints=critical,CA:TRUE",
            "-addext",
            "keyUsage=critical,keyCertSign,cRLSign",
        ]);
        self.run(&args)
    }

    /// A certificate for a server and a client alike, signed by the authority `ca`
    /// (made by [`Openssl::ca`]): `NAME.key` and `NAME.crt`, common name `cn`,
    /// subject alternative names `san` (e.g. `IP:127.0.0.1,DNS:localhost`).
    pub fn leaf(&self, name: &str, cn: &str, ca: &str, san: &str) -> Result<(), String> {
        let (key, csr, crt, ext) =
            (format!("{name}.key"), format!("{name}.csr"), format!("{name}.crt"), format!("{name}.ext"));
        let extensions = format!(
            "basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature\n\
             extendedKeyUsage=serverAuth,clientAuth\nsubjectAltName={san}\n"
        );
        std::fs::write(self.dir.join(&ext), extensions).map_err(|e| format!("cannot write {ext}: {e}"))?;
        let subject = format!("/CN={cn}");
        let mut req = vec!["req"];
        req.extend(EC_KEY);
        req.extend(["-keyout", &key, "-out", &csr, "-subj", &subject]);
        self.run(&req)?;
        let (ca_crt, ca_key) = (format!("{ca}.crt"), format!("{ca}.key"));
        self.run(&[
            "x509",
            "-req",
            "-in",
            &csr,
            "-CA",
            &ca_crt,
            "-CAkey",
            &ca_key,
            "-CAcreateserial",
            "-days",
            "2",
            "-out",
            &crt,
            "-extfile",
            &ext,
        ])
    }

    /// The path of `file` in the folder.
    pub fn path(&self, file: &str) -> PathBuf {
        self.dir.join(file)
    }
}
