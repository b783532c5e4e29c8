//! The pure parts of `mireg merge` against known transforms: two sessions drawn from one route
//! with a known alignment between their worlds; links from the truth agree and a link to a
//! look-alike place does not; the groups compose the joins' alignments; the joint graph puts the
//! later session where the truth does.

use mireg::loops::LoopConfig;
use mireg::merge::graph::solve_group;
use mireg::merge::links::{AgreementConfig, Track, agreeing_links, links_agree};
use mireg::merge::{Join, LinkSource, SessionLink, group_sessions};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn pose(x: f64, y: f64, z: f64, roll: f64, pitch: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    )
}

/// A route of `n` poses in the true world: a lap of a 10 m circle with some height.
fn route(n: usize) -> Vec<Isometry3<f64>> {
    (0..n)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            pose(
                10.0 * a.cos(),
                10.0 * a.sin(),
                0.2 * a.sin(),
                0.0,
                0.0,
                a + 1.5,
            )
        })
        .collect()
}

/// Two sessions along the same route (every second pose each, offset by one), each in its own
/// world (its first frame), and the truth `world_a_from_world_b`.
fn two_sessions() -> (Vec<Isometry3<f64>>, Vec<Isometry3<f64>>, Isometry3<f64>) {
    let r = route(80);
    let a: Vec<_> = r.iter().step_by(2).copied().collect();
    let b: Vec<_> = r.iter().skip(1).step_by(2).copied().collect();
    let (a0, b0) = (a[0], b[0]);
    let own = |s: &[Isometry3<f64>], o: Isometry3<f64>| s.iter().map(|p| o.inverse() * p).collect();
    (own(&a, a0), own(&b, b0), a0.inverse() * b0)
}

fn link(
    a: &[Isometry3<f64>],
    b: &[Isometry3<f64>],
    fa: usize,
    fb: usize,
    truth: &Isometry3<f64>,
) -> SessionLink {
    SessionLink {
        a: 0,
        frame_a: fa,
        b: 1,
        frame_b: fb,
        a_from_b: a[fa].inverse() * truth * b[fb],
        information: None,
        inliers: 100,
        found_by: LinkSource::Appearance,
    }
}

fn travelled(p: &[Isometry3<f64>]) -> Vec<f64> {
    mireg::evaluate::path_distances(p)
}

#[test]
fn true_links_agree_and_a_look_alike_does_not() {
    let (a, b, truth) = two_sessions();
    let (ta, tb) = (travelled(&a), travelled(&b));
    let tracks = [
        Track {
            poses: &a,
            travelled_m: &ta,
        },
        Track {
            poses: &b,
            travelled_m: &tb,
        },
    ];
    let config = AgreementConfig::for_voxel(0.1);
    let mut links: Vec<SessionLink> = [(3, 3), (10, 9), (20, 21), (31, 30)]
        .iter()
        .map(|&(fa, fb)| link(&a, &b, fa, fb, &truth))
        .collect();
    // Each true link implies the truth.
    for l in &links {
        let d = truth.inverse() * l.alignment(&a, &b);
        assert!(d.translation.vector.norm() < 1e-9 && d.rotation.angle() < 1e-9);
    }
    // A look-alike: the registration of frames 15/15 as if b stood 3 m further along.
    let mut wrong = link(&a, &b, 15, 15, &truth);
    wrong.a_from_b *= Isometry3::translation(3.0, 0.0, 0.0);
    wrong.inliers = 500;
    links.push(wrong);
    assert!(links_agree(&links[0], &links[1], &tracks, &config));
    assert!(!links_agree(&links[0], &links[4], &tracks, &config));
    assert_eq!(
        agreeing_links(&links, (0, 1), &tracks, &config),
        vec![0, 1, 2, 3]
    );
}

#[test]
fn groups_compose_the_joins_alignments() {
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let mut random = || {
        pose(
            rng.random_range(-20.0..20.0),
            rng.random_range(-20.0..20.0),
            rng.random_range(-2.0..2.0),
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
            rng.random_range(-3.1..3.1),
        )
    };
    // World of each of 5 sessions in one true frame; sessions 0-2 and 3-4 meet, the groups not.
    let worlds: Vec<Isometry3<f64>> = (0..5).map(|_| random()).collect();
    let join = |a: usize, b: usize, links: usize| Join {
        a,
        b,
        a_from_b: worlds[a].inverse() * worlds[b],
        links,
    };
    let joins = [join(1, 2, 5), join(0, 2, 3), join(0, 1, 2), join(3, 4, 2)];
    let groups = group_sessions(5, &joins);
    assert_eq!(groups.len(), 2);
    assert_eq!(groups[0].members, vec![0, 2, 1]);
    assert_eq!(groups[1].members, vec![3, 4]);
    for g in &groups {
        let root = worlds[g.members[0]];
        for (m, align) in g.members.iter().zip(&g.alignments) {
            let truth = root.inverse() * worlds[*m];
            let d = truth.inverse() * align;
            assert!(d.translation.vector.norm() < 1e-9 && d.rotation.angle() < 1e-9);
        }
    }
    // A session that joins nothing is a group of its own.
    assert_eq!(group_sessions(3, &[join(0, 1, 2)])[1].members, vec![2]);
}

#[test]
fn the_joint_graph_puts_the_later_session_where_the_truth_does() {
    let (a, b, truth) = two_sessions();
    let links: Vec<SessionLink> = [(3, 3), (20, 21), (31, 30)]
        .iter()
        .map(|&(fa, fb)| link(&a, &b, fa, fb, &truth))
        .collect();
    // Start from an alignment 0.5 m and 3° off: the links must pull it to the truth.
    let off = truth * pose(0.5, -0.3, 0.1, 0.0, 0.0, 3f64.to_radians());
    let config = LoopConfig::for_voxel(0.1);
    let s = solve_group(
        &[&a, &b],
        &[0, 1],
        &[Isometry3::identity(), off],
        &links,
        &config,
    )
    .unwrap();
    for (k, p) in s.poses[1].iter().enumerate() {
        let expected = truth * b[k];
        let e: Vector3<f64> = p.translation.vector - expected.translation.vector;
        assert!(e.norm() < 1e-4, "frame {k}: {:.6} m off", e.norm());
    }
    assert!(
        s.link_weights.iter().all(|w| *w > 0.9),
        "{:?}",
        s.link_weights
    );
    // The root stays where it was.
    assert!((s.poses[0][0].translation.vector).norm() < 1e-12);
}
