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
                &[],
            )
        })
        .collect();
    let out = dir.path().join("farm.png");
    let mut sub = spawn_farm_submit(&dir, &url, &scene, &out, 16);
    let rt = runtime();
    let total = 8 * 6;
    let mut kills = 0;
    // Kill after a few tiles, in the middle, and at once after a restart
    // (while it is resuming or has just resumed).
    for (i, at) in [3u64, 20, 0].into_iter().enumerate() {
        if at > 0 {
            wait_for(&dir, &format!("{at} tiles done"), 120, || {
                try_job(&rt, &c, 1).is_some_and(|s| s.tiles_done >= at)
            });
        }
        let s = try_job(&rt, &c, 1);
        if let Some(s) = &s {
            assert_eq!(s.tiles_total, total);
            assert!(
                s.tiles_done < s.tiles_total,
                "the job ended before kill {i}; make the scene slower\n{}",
                dir.logs()
            );
        }
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
        if at > 0 {
            let s = try_job(&rt, &c, 1).expect("the job survived the restart");
            assert!(s.tiles_done >= at, "{s:?}\n{}", dir.logs());
        }
    }
    let status = wait_child(&dir, &mut sub, 180);
    assert!(status.success(), "submit failed\n{}", dir.logs());
    assert!(
        std::fs::read(&out).unwrap() == expected,
        "output differs from the undisturbed render\n{}",
        dir.logs()
    );
    let s = try_job(&rt, &c, 1).unwrap();
    assert_eq!(s.state, pb::JobState::Done as i32);
    assert_eq!(s.tiles_done, total);
    let n = tiles_rendered(&dir, WORKERS);
    // A lease spans at most one band of tiles (8 here, lease sizing), so a
    // kill can cost each worker at most its leases in flight of a band each.
    const BAND: usize = 8;
    let bound = total as usize + kills * WORKERS * TILES_IN_FLIGHT * BAND;
    assert!(
        n <= bound,
        "rendered {n} tiles for {total}, more than {bound}\n{}",
        dir.logs()
    );
    assert!(n >= total as usize, "the worker logs count {n} tiles");
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
