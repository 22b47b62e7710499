//! The MuJoCo chain works: libmujoco 3.17.0 is found, an MJCF scene loads and steps, and the
//! result matches what the integrator must produce.

use mujoco_rs::prelude::*;

const SCENE: &str = r#"
<mujoco>
  <option timestep="0.002" gravity="0 0 -9.81" integrator="Euler"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="box" pos="0 0 2">
      <freejoint/>
      <geom type="box" size="0.1 0.1 0.1" mass="1"/>
    </body>
  </worldbody>
</mujoco>
"#;

#[test]
fn mjcf_scene_loads_and_falls_as_semi_implicit_euler_says() {
    let model = MjModel::from_xml_string(SCENE).expect("scene loads");
    assert_eq!(model.ffi().nq, 7);
    assert_eq!(model.ffi().nv, 6);
    let mut data = model.make_data();
    let dt = 0.002;
    let n = 200; // 0.4 s: falls 0.78 m, far from the floor
    for _ in 0..n {
        data.step();
    }
    let z = data.qpos()[2];
    // Semi-implicit Euler: v_k = -g dt k, z_n = z0 - g dt^2 n (n + 1) / 2.
    let expected = 2.0 - 9.81 * dt * dt * (n * (n + 1)) as f64 / 2.0;
    assert!((z - expected).abs() < 1e-9, "z = {z}, expected {expected}");
    assert!((data.qvel()[2] + 9.81 * dt * n as f64).abs() < 1e-9);
    assert!((data.ffi().time - dt * n as f64).abs() < 1e-12);
}

#[test]
fn malformed_scene_is_an_error_not_a_crash() {
    let err = MjModel::from_xml_string(
        "<mujoco><worldbody><body><geom type=\"nonsense\"/></body></worldbody></mujoco>",
    );
    assert!(err.is_err());
}
