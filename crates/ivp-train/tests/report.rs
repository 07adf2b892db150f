//! `ivp eval --report` end to end: the report of a committed Blender clip, opened in headless
//! Chromium, loads every image without an error, sorts its frames, and shows the numbers the
//! evaluation computed. Chromium is required: without it this test fails (CI installs it).

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Chromium: `IVP_CHROMIUM`, else `/usr/bin/chromium`, else `chromium` on the PATH.
fn chromium() -> PathBuf {
    if let Some(path) = std::env::var_os("IVP_CHROMIUM") {
        return PathBuf::from(path);
    }
    let standard = PathBuf::from("/usr/bin/chromium");
    if standard.is_file() {
        return standard;
    }
    let on_path = std::env::var_os("PATH")
        .and_then(|paths| std::env::split_paths(&paths).map(|d| d.join("chromium")).find(|p| p.is_file()));
    on_path.unwrap_or_else(|| {
        panic!(
            "this test opens the report in a real browser and needs Chromium: install it (`apt-get install chromium`, \
             as .ci/run does) or point IVP_CHROMIUM at it"
        )
    })
}

/// Runs headless Chromium on `url` with `args`, in a profile of its own; its stdout and stderr.
fn run_chromium(url: &str, args: &[&str], profile: &Path) -> (String, String) {
    let out = Command::new(chromium())
        .args(["--headless", "--disable-gpu", "--no-sandbox", "--no-first-run", "--disable-extensions"])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(args)
        .arg(url)
        .output()
        .expect("running chromium");
    let (stdout, stderr) =
        (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned());
    assert!(out.status.success(), "chromium {args:?} failed: {stderr}");
    (stdout, stderr)
}

/// Every `src="..."` and `href="..."` value of a page.
fn links(html: &str) -> Vec<String> {
    let mut out = Vec::new();
    for attr in ["src=\"", "href=\""] {
        for (i, _) in html.match_indices(attr) {
            let rest = &html[i + attr.len()..];
            out.push(rest[..rest.find('"').unwrap()].to_string());
        }
    }
    out
}

/// Injected at the top of a copy of the page: records load failures, uncaught errors and
/// console errors, then once everything has loaded checks every image, picks the order "where
/// the methods differ most", and writes what it found into the page as JSON.
const CHECK: &str = r#"<script>
var problems = [];
window.addEventListener('error', function (e) {
  var t = e.target;
  if (t && t !== window && (t.src || t.href)) { problems.push('failed to load ' + (t.src || t.href)); }
  else { problems.push('uncaught: ' + e.message); }
}, true);
var consoleError = console.error;
console.error = function () { problems.push('console.error: ' + Array.from(arguments).join(' ')); consoleError.apply(console, arguments); };
window.addEventListener('load', function () {
  var images = Array.from(document.images);
  var broken = images.filter(function (i) { return !(i.complete && i.naturalWidth > 0); }).map(function (i) { return i.getAttribute('src'); });
  var order = document.getElementById('order');
  order.value = 'spread';
  order.dispatchEvent(new Event('change'));
  var sorted = Array.from(document.getElementById('frames').children).map(function (s) { return s.id; });
  var spreads = Array.from(document.getElementById('frames').children).map(function (s) { return parseFloat(s.getAttribute('data-spread')); });
  var out = document.createElement('pre');
  out.id = 'ivp-check';
  out.textContent = JSON.stringify({ images: images.length, broken: broken, problems: problems, sorted: sorted, spreads: spreads });
  document.body.appendChild(out);
});
</script>"#;

#[test]
fn the_report_of_a_blender_clip_loads_every_image_in_chromium() {
    let browser = chromium();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("report");
    let json = tmp.path().join("scores.json");
    let clip = repo().join("data/blender-dev/clip_000");
    let model = |name: &str, variant: &str| {
        format!("{name}={}", repo().join("results/ablate").join(variant).join("seed0/model.safetensors").display())
    };
    let run = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_ivp"))
            .args(["--quiet", "eval", "--data"])
            .arg(&clip)
            .args(["--methods", "fill,telea", "--targets", "6,8", "--model", &model("full", "full")])
            .args(["--model", &model("no-tg", "no-tg"), "--json"])
            .arg(&json)
            .arg("--report")
            .arg(&dir)
            .args(extra)
            .output()
            .expect("running ivp")
    };
    let out = run(&[]);
    assert!(out.status.success(), "ivp eval --report failed: {}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("report written to"), "{stdout}");

    // A second run into the same folder is refused, naming it; --force writes over it.
    let again = run(&[]);
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert!(
        !again.status.success() && stderr.contains(&dir.display().to_string()) && stderr.contains("--force"),
        "{stderr}"
    );
    assert!(run(&["--force"]).status.success());

    // The page shows the numbers the evaluation computed: every frame's D-MSE of every method.
    let html = std::fs::read_to_string(dir.join("index.html")).unwrap();
    let scores: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let frames = scores["per_frame"].as_array().unwrap();
    assert_eq!(frames.len(), 2);
    for frame in frames {
        for method in ["fill", "telea", "full", "no-tg"] {
            let d_mse = frame["d_mse"][method].as_f64().unwrap();
            assert!(html.contains(&format!("<td>{d_mse:.1}</td>")), "{method}: D-MSE {d_mse:.1} not on the page");
        }
    }
    for method in ["fill", "telea", "full", "no-tg"] {
        let d_mse = scores["methods"][method]["d_mse"].as_f64().unwrap();
        assert!(html.contains(&format!("<td>{d_mse:.1}</td>")), "{method}: pooled D-MSE not on the page");
    }

    // Every link is to a file of the folder; nothing is fetched from elsewhere.
    let linked = links(&html);
    assert!(linked.len() > 20, "{linked:?}");
    for link in &linked {
        assert!(!link.contains("://") && !link.starts_with('/') && !link.contains(".."), "not a local link: {link}");
        assert!(link.starts_with('#') || dir.join(link).is_file(), "broken link: {link}");
    }
    let total: u64 = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().metadata().unwrap().len()).sum();
    assert!(total < 1_500_000, "a report of 2 frames takes {total} bytes");

    // In the browser: every image loads, no error, and the sort control orders by spread.
    let check = dir.join("check.html");
    std::fs::write(&check, html.replacen("<head>", &format!("<head>{CHECK}"), 1)).unwrap();
    let url = |p: &Path| format!("file://{}", p.canonicalize().unwrap().display());
    let profile = tmp.path().join("profile");
    let (dom, stderr) = run_chromium(
        &url(&check),
        &[
            "--allow-file-access-from-files",
            "--virtual-time-budget=10000",
            "--enable-logging=stderr",
            "--v=0",
            "--dump-dom",
        ],
        &profile,
    );
    let start = dom.find("<pre id=\"ivp-check\">").unwrap_or_else(|| panic!("the check did not run: {dom}\n{stderr}"));
    let body = &dom[start + "<pre id=\"ivp-check\">".len()..];
    let text = body[..body.find("</pre>").unwrap()].replace("&amp;", "&").replace("&lt;", "<").replace("&gt;", ">");
    let found: serde_json::Value = serde_json::from_str(&text).unwrap();
    let images = found["images"].as_u64().unwrap();
    let expected = linked.iter().filter(|l| l.ends_with(".png") || l.ends_with(".svg")).count() as u64;
    assert_eq!(images, expected, "{found}");
    assert!(found["broken"].as_array().unwrap().is_empty(), "images that did not load: {}", found["broken"]);
    assert!(found["problems"].as_array().unwrap().is_empty(), "errors in the page: {}", found["problems"]);
    assert!(!stderr.contains("Uncaught"), "{stderr}");
    let spreads: Vec<f64> = found["spreads"].as_array().unwrap().iter().map(|s| s.as_f64().unwrap()).collect();
    assert_eq!(spreads.len(), 2);
    assert!(spreads[0] >= spreads[1], "not sorted by spread: {spreads:?}");

    // A screenshot, for a person to look at (target/tmp/report.png).
    let screenshot = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("report.png");
    let _ = std::fs::remove_file(&screenshot);
    run_chromium(
        &url(&dir.join("index.html")),
        &[&format!("--screenshot={}", screenshot.display()), "--window-size=1280,2000", "--hide-scrollbars"],
        &profile,
    );
    let shot = ivp_data::read_rgb(&screenshot).expect("chromium wrote the screenshot");
    assert_eq!((shot.width(), shot.height()), (1280, 2000));
    // Not a blank page: the crops and charts bring many colours.
    let colours: std::collections::BTreeSet<[u8; 3]> =
        shot.pixels().iter().map(|p| p.map(|c| (c * 255.0).round() as u8)).collect();
    assert!(colours.len() > 500, "{} colours in the screenshot", colours.len());
    println!("chromium: {}; screenshot: {}", browser.display(), screenshot.display());
}
