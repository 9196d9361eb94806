//! Reconstructs one frame of a built-in scene with TFP, straight from the libraries (no dora), and
//! writes it beside the ground truth as one PNG.
//!
//! `cargo run --release --example tfp_vs_truth -- bright-slow docs/tfp-vs-truth.png`

use ndarray::{Array2, Array3, s};
use neuspike_image::{BitDepth, write_frame_png};
use neuspike_metrics::{psnr, ssim};
use neuspike_reconstruction::luminance_from_rate_into;
use neuspike_representations::tfp_into;
use neuspike_scene::Scene;
use neuspike_spike_camera::{CameraConfig, SpikeCamera};

/// Planes in the TFP window, centred on the reference plane.
const WINDOW: usize = 33;
/// The reference plane.
const REF_PLANE: u64 = 400;

fn main() -> eyre::Result<()> {
    let mut args = std::env::args().skip(1);
    let scene = args.next().unwrap_or_else(|| "bright-slow".into());
    let out = args.next().unwrap_or_else(|| "tfp-vs-truth.png".into());
    let mut cam = SpikeCamera::new(Scene::load(&scene)?, CameraConfig::default())?;
    let first = REF_PLANE - (WINDOW / 2) as u64;
    // Run the camera up to the window, then take the window's planes.
    let _ = cam.next_chunk(first as usize, 0);
    let chunk = cam.next_chunk(WINDOW, 1);
    let (h, w) = (chunk.height, chunk.width);
    let mut planes = Array3::<u8>::zeros((WINDOW, h, w));
    chunk.unpack_into(planes.view_mut());
    let mut rate = Array2::<f32>::zeros((h, w));
    tfp_into(planes.view(), rate.view_mut())?;
    let mut tfp = Array2::<f32>::zeros((h, w));
    luminance_from_rate_into(rate.view(), cam.lum_per_rate(), 1.0, tfp.view_mut())?;
    let truth = cam.ground_truth(REF_PLANE);
    println!(
        "{scene}: TFP ({WINDOW} planes) PSNR {:.2} dB, SSIM {:.4}",
        psnr(tfp.view(), truth.view()),
        ssim(tfp.view(), truth.view())
    );
    let gap = 8;
    let mut both = Array2::<f32>::ones((h, 2 * w + gap));
    both.slice_mut(s![.., ..w]).assign(&tfp);
    both.slice_mut(s![.., w + gap..]).assign(&truth);
    write_frame_png(std::path::Path::new(&out), both.view(), BitDepth::Eight)?;
    println!("wrote {out} (left: TFP, right: ground truth)");
    Ok(())
}
