//! The coordinator keeps its work: `kill -9` at several points of a job,
//! restart on the same address and data directory, and the job finishes with
//! the same bytes as an undisturbed render, without rendering finished tiles
//! again. Workers and the waiting `trevi-submit` reconnect by themselves.

mod common;

use common::*;
use trevi_proto::pb;

const TILES_IN_FLIGHT: usize = 2;
const WORKERS: usize = 2;
const SHORT_LEASES: &[&str] = &["--lease-target-ms", "100"];

#[test]
fn kill_9_of_the_coordinator_at_several_points_loses_nothing() {
    let dir = Dir::new();
    // 8 × 6 tiles of 16, slow enough that every kill lands mid-job.
    let scene = dir.write(
        "s.xml",
        &SLOW_SCENE.replace(r#"width="96" height="64""#, r#"width="128" height="96""#),
    );
    let expected = embedded(&dir, &scene, "embedded.png");
    // Leases of a tenth of a second: a one-second lease of whole bands
    // would bring half the frame at once, and the kills would not land
    // mid-job.
    let mut c = coordinator_with(&dir, "127.0.0.1:0", "coordinator0", SHORT_LEASES, &[]);
    let (url, addr) = (c.url.clone(), c.addr.clone());
    let workers: Vec<Proc> = (0..WORKERS)
        .map(|i| {
            worker_with(
                &dir,
                &url,
                &format!("worker{i}"),
                &["--tiles-in-flight", &TILES_IN_FLIGHT.to_string()],
                // A lease takes at least a tenth of a second, so the
                // lease sizer keeps leases to a tile or two and the job
                // lasts over a second however idle the machine: the kills
                // land mid-job.
                &[("TREVI_TEST_LEASE_DELAY_MS", "100")],
            )
        })
        .collect();
    let out = dir.path().join("farm.png");
    let mut sub = spawn_farm_submit(&dir, &url, &scene, &out, 16);
    let rt = runtime();
    let total = 8 * 6;
    let mut kills = 0;
    // Tiles rendered but lost at each kill, at most: the distinct tiles the
    // workers' logs show rendered by the time the restarted coordinator is
    // asked, less the tiles it found done (a finished tile is never lost).
    let mut lost_at_kills = 0;
    // Kill after a few tiles, in the middle, and at once after a restart
    // (while it is resuming or has just resumed).
    for (i, at) in [3u64, 20, 0].into_iter().enumerate() {
        if at > 0 {
            wait_for(&dir, &format!("{at} tiles done"), 120, || {
                try_job(&rt, &c, 1).is_some_and(|s| s.tiles_done >= at)
            });
        }
        // The coordinator answers (a restarted one may still be opening
        // its store): the check is made every time, never skipped.
        let mut s = None;
        wait_for(&dir, "the coordinator to answer", 60, || {
            s = try_job(&rt, &c, 1);
            s.is_some()
        });
        let s = s.unwrap();
        assert_eq!(s.tiles_total, total);
        assert!(
            s.tiles_done < s.tiles_total,
            "the job ended before kill {i}; make the scene slower\n{}",
            dir.logs()
        );
        drop(c); // SIGKILL
        kills += 1;
        c = coordinator_with(
            &dir,
            &addr,
            &format!("coordinator{}", i + 1),
            SHORT_LEASES,
            &[],
        );
        // What the restarted coordinator found.
        let mut found = None;
        wait_for(&dir, "the restarted coordinator to answer", 60, || {
            found = try_job(&rt, &c, 1);
            found.is_some()
        });
        let found = found.expect("the job survived the restart");
        assert!(found.tiles_done >= at, "{found:?}\n{}", dir.logs());
        let rendered = rendered_tiles(&dir)
            .into_iter()
            .collect::<std::collections::BTreeSet<_>>();
        lost_at_kills += rendered.len() as u64 - found.tiles_done.min(rendered.len() as u64);
    }
    let status = wait_child(&dir, &mut sub, 180);
    assert!(status.success(), "submit failed\n{}", dir.logs());
    assert!(
        std::fs::read(&out).unwrap() == expected,
        "output differs from the undisturbed render\n{}",
        dir.logs()
    );
    assert_same_pixels(
        &expected,
        &core_render(&dir, &scene, "core.png"),
        "the undisturbed render",
    );
    let s = try_job(&rt, &c, 1).unwrap();
    assert_eq!(s.state, pb::JobState::Done as i32);
    assert_eq!(s.tiles_done, total);
    let tiles = rendered_tiles(&dir);
    let n = tiles.len() as u64;
    assert_eq!(
        n as usize,
        tiles_rendered(&dir, WORKERS),
        "a log line not understood"
    );
    // Besides the tiles lost at a kill, a worker may finish tiles it was
    // rendering when the coordinator died, to no avail: at most its leases
    // in flight, each of the widest span the logs show.
    let widest = widest_span(&dir);
    let in_flight = kills * (WORKERS * TILES_IN_FLIGHT) as u64 * widest;
    let bound = total + lost_at_kills + in_flight;
    assert!(
        n <= bound,
        "rendered {n} tiles for {total}: more than {total} + {lost_at_kills} lost at the \
         kills + {in_flight} in flight; a finished tile was rendered again\n{}",
        dir.logs()
    );
    // Every tile was rendered.
    let distinct = tiles
        .iter()
        .collect::<std::collections::BTreeSet<_>>()
        .len() as u64;
    assert_eq!(distinct, total, "{}", dir.logs());
    // The finished job and its output survive one more restart.
    drop(c);
    let c = coordinator_with(&dir, &addr, "coordinator-last", &[], &[]);
    let again = dir.path().join("again.png");
    let o = submit(&dir, &["status", "1", "--coordinator", &c.url]);
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("done"),
        "{}",
        dir.logs()
    );
    let bytes = rt.block_on(download(&c, 1, None));
    std::fs::write(&again, &bytes).unwrap();
    assert!(bytes == expected);
    drop(workers);
}

/// Tiles of the 128 × 96 frame (8 columns of 16) the workers' logs show
/// rendered, one entry a render: a "tile rendered" line per tile, the tiles
/// of one lease (a span) in a row with consecutive lease ids and the
/// span's corner (`x`, `y`), its tiles in order from there.
fn rendered_tiles(dir: &Dir) -> Vec<u64> {
    let mut tiles = Vec::new();
    for w in 0..WORKERS {
        let log = dir.read_log(&format!("worker{w}"));
        // (x, y, first lease id) of the span the last line was in.
        let mut span: Option<(u64, u64, u64)> = None;
        let mut last_id = 0;
        for line in log.lines().filter(|l| l.contains("tile rendered")) {
            let field = |name: &str| -> u64 {
                line.split_whitespace()
                    .find_map(|f| f.strip_prefix(name)?.strip_prefix('='))
                    .and_then(|v| v.parse().ok())
                    .unwrap_or_else(|| panic!("no {name} in {line:?}"))
            };
            let (id, x, y) = (field("lease"), field("x"), field("y"));
            let (sx, sy, first) = match span {
                Some((sx, sy, first)) if (sx, sy) == (x, y) && id == last_id + 1 => (sx, sy, first),
                _ => (x, y, id),
            };
            span = Some((sx, sy, first));
            last_id = id;
            tiles.push((sy / 16) * 8 + sx / 16 + (id - first));
        }
    }
    tiles
}

/// The most tiles one lease of the logs covered.
fn widest_span(dir: &Dir) -> u64 {
    let mut widest = 1;
    for w in 0..WORKERS {
        let log = dir.read_log(&format!("worker{w}"));
        let (mut run, mut last) = (0u64, None::<(u64, String)>);
        for line in log.lines().filter(|l| l.contains("tile rendered")) {
            let id: u64 = line
                .split_whitespace()
                .find_map(|f| f.strip_prefix("lease="))
                .and_then(|v| v.parse().ok())
                .unwrap();
            let at: String = line
                .split_whitespace()
                .filter(|f| f.starts_with("x=") || f.starts_with("y="))
                .collect();
            run = match &last {
                Some((prev, prev_at)) if *prev + 1 == id && *prev_at == at => run + 1,
                _ => 1,
            };
            widest = widest.max(run);
            last = Some((id, at));
        }
    }
    widest
}

/// A scene with `cams` cameras, each writing its own small PNG.
fn many_camera_scene(seed: u32, cams: u32) -> String {
    let mut s = format!(
        r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.1 0.1 0.1"/>
  <sphere id="ball" center="0 1 0" radius="{}">
    <surface diffuse="0.8 0.3 0.2"/>
  </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1"/>
"#,
        0.6 + seed as f32 * 0.1
    );
    for c in 0..cams {
        s.push_str(&format!(
            r#"  <camera id="c{c}" position="{} 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="40" height="24" output="c{c}.png"/>
  </camera>
"#,
            c as f32 * 0.3 - 1.5
        ));
    }
    s.push_str("</scene>\n");
    s
}

#[test]
fn five_submitters_fifty_jobs_four_workers() {
    let dir = Dir::new();
    const SUBMITTERS: u32 = 5;
    const CAMS: u32 = 10;
    let scenes: Vec<std::path::PathBuf> = (0..SUBMITTERS)
        .map(|i| dir.write(&format!("s{i}/scene.xml"), &many_camera_scene(i, CAMS)))
        .collect();
    // The expected images: each scene rendered by the embedded farm.
    for (i, s) in scenes.iter().enumerate() {
        let o = submit(&dir, &[s.to_str().unwrap(), "--tile", "16", "--quiet"]);
        assert!(
            o.status.success(),
            "embedded render {i} failed\n{}",
            dir.logs()
        );
        for c in 0..CAMS {
            let p = s.parent().unwrap().join(format!("c{c}.png"));
            std::fs::rename(&p, p.with_extension("expected.png")).unwrap();
        }
    }
    let c = coordinator_with(&dir, "127.0.0.1:0", "coordinator", &[], &[]);
    let workers: Vec<Proc> = (0..4)
        .map(|i| worker_with(&dir, &c.url, &format!("worker{i}"), &[], &[]))
        .collect();
    let mut subs: Vec<std::process::Child> = scenes
        .iter()
        .enumerate()
        .map(|(i, s)| {
            submit_cmd(&[
                s.to_str().unwrap(),
                "--coordinator",
                &c.url,
                "--tile",
                "16",
                "--priority",
                &(i as i32 % 3).to_string(),
            ])
            .stderr(dir.log(&format!("submitter{i}")))
            .spawn()
            .unwrap()
        })
        .collect();
    for s in &mut subs {
        let st = wait_child(&dir, s, 120);
        assert!(st.success(), "a submitter failed\n{}", dir.logs());
    }
    for s in &scenes {
        for cam in 0..CAMS {
            let p = s.parent().unwrap().join(format!("c{cam}.png"));
            let got = std::fs::read(&p).unwrap();
            let want = std::fs::read(p.with_extension("expected.png")).unwrap();
            assert!(got == want, "{} differs\n{}", p.display(), dir.logs());
        }
    }
    let rt = runtime();
    let list = rt.block_on(async {
        jobs(&c, None)
            .await
            .list_jobs(pb::ListJobsRequest::default())
            .await
            .unwrap()
            .into_inner()
            .jobs
    });
    assert_eq!(list.len(), (SUBMITTERS * CAMS) as usize);
    let tiles: u64 = list.iter().map(|s| s.tiles_total).sum();
    for s in &list {
        assert_eq!(s.state, pb::JobState::Done as i32, "{s:?}");
        assert_eq!(s.tiles_done, s.tiles_total, "{s:?}");
    }
    // Every tile rendered once: none lost, none done twice.
    let rendered = tiles_rendered(&dir, 4);
    assert_eq!(rendered as u64, tiles, "{}", dir.logs());
    drop(workers);
}
