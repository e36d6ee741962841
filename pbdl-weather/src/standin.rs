//! A stand-in climate on the WeatherBench 32 x 64 grid, made by the project's own
//! forced-dissipative shallow-water model ([`crate::shallow_water`]): no download needed.
//!
//! The defaults follow the forced-dissipative test of `tests/williamson.rs`: fast (1-day)
//! relaxation toward sharp jets with weak drag keeps the jets barotropically unstable, so the
//! flow stays unsteady (10-day relaxation with 20-day drag settled into a steady wave within 90
//! days). Over two years (seed 0) the default gives a Z500-like climatology RMSE of 1256
//! m^2/s^2 and persistence RMSEs of 215 / 370 / 378 at 1 / 3 / 5 days.
//!
//! The layer geopotential is relaxed toward a zonal equilibrium with a westerly jet in each
//! hemisphere that moves and strengthens with the seasons, plus large-scale random anomalies
//! (red noise, a few days' memory) that keep the flow unsteady; two Gaussian mountains make
//! stationary waves; linear drag and del^4 hyperdiffusion remove energy. A tracer relaxed toward
//! an equator-to-pole temperature profile with a seasonal cycle and advected by the flow stands in
//! for T850. Output every `output_hours`, interpolated to the WeatherBench latitudes:
//! `z` = g (h + h_s) in m^2/s^2 (Z500-like, about 5.4e4) and `t` in K (T850-like).
//!
//! [`ClimateConfig::biased`] changes the jet, the forcing and the noise: a long run of it stands
//! in for the climate model (CMIP) the paper pretrains on, a shorter run of the default for ERA5.

use crate::error::{Error, Result};
use crate::field::{Field, Values};
use crate::grid::LatLonGrid;
use crate::shallow_water::{to_weatherbench, GaussianGrid, Hyperdiffusion, ModelParams, ShallowWater};
use crate::time::Seconds;
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// Settings of a stand-in climate run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClimateConfig {
    /// Spectral truncation (21 on the 32 x 64 grid).
    pub truncation: usize,
    /// Gaussian latitudes.
    pub n_lat: usize,
    /// Time step in seconds.
    pub dt: f64,
    /// Hours between stored fields.
    pub output_hours: u32,
    /// Mean layer depth (m).
    pub mean_depth: f64,
    /// Annual-mean jet latitude (degrees).
    pub jet_latitude: f64,
    /// Seasonal excursion of the jet latitude (degrees, equatorward in winter).
    pub jet_seasonal_shift: f64,
    /// Width of the jet's height step (degrees).
    pub jet_width: f64,
    /// Height drop across each jet (m).
    pub jet_drop: f64,
    /// Relative seasonal change of the drop (stronger in winter).
    pub jet_seasonal_amplitude: f64,
    /// Relaxation time of the geopotential (days).
    pub relaxation_days: f64,
    /// Linear drag time on vorticity and divergence (days).
    pub drag_days: f64,
    /// E-folding time (hours) of del^4 hyperdiffusion at the truncation wavenumber.
    pub hyperdiffusion_hours: f64,
    /// Standard deviation of the random equilibrium anomalies (m).
    pub noise_height: f64,
    /// Memory of the random anomalies (days).
    pub noise_days: f64,
    /// Mountain height (m) of the two Gaussian mountains.
    pub mountain_height: f64,
    /// Equator-to-pole contrast of the tracer's equilibrium (K).
    pub tracer_contrast: f64,
    /// Relaxation time of the tracer (days).
    pub tracer_days: f64,
    /// Seed of the random anomalies.
    pub seed: u64,
}

impl Default for ClimateConfig {
    fn default() -> Self {
        Self {
            truncation: 21,
            n_lat: 32,
            dt: 1200.0,
            output_hours: 6,
            mean_depth: 5500.0,
            jet_latitude: 45.0,
            jet_seasonal_shift: 5.0,
            jet_width: 6.0,
            jet_drop: 1000.0,
            jet_seasonal_amplitude: 0.2,
            relaxation_days: 1.0,
            drag_days: 100.0,
            hyperdiffusion_hours: 48.0,
            noise_height: 200.0,
            noise_days: 3.0,
            mountain_height: 2000.0,
            tracer_contrast: 40.0,
            tracer_days: 8.0,
            seed: 0,
        }
    }
}

impl ClimateConfig {
    /// The "climate model": jet 4 degrees poleward and 15% stronger, 20% more noise, a
    /// 10% larger temperature contrast, and its own seed.
    pub fn biased(seed: u64) -> Self {
        let base = Self::default();
        Self {
            jet_latitude: base.jet_latitude + 4.0,
            jet_drop: base.jet_drop * 1.15,
            noise_height: base.noise_height * 1.2,
            tracer_contrast: base.tracer_contrast * 1.1,
            seed,
            ..base
        }
    }

    fn check(&self) -> Result<()> {
        let positive = [
            ("dt", self.dt),
            ("mean_depth", self.mean_depth),
            ("jet_width", self.jet_width),
            ("relaxation_days", self.relaxation_days),
            ("drag_days", self.drag_days),
            ("noise_days", self.noise_days),
            ("tracer_days", self.tracer_days),
            ("hyperdiffusion_hours", self.hyperdiffusion_hours),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::InvalidArgument(format!("stand-in climate: {name} = {v} must be positive")));
            }
        }
        if self.output_hours == 0 || (self.output_hours as f64 * 3600.0) % self.dt != 0.0 {
            return Err(Error::InvalidArgument(format!(
                "stand-in climate: output every {} h must be a whole number of {} s steps",
                self.output_hours, self.dt
            )));
        }
        Ok(())
    }
}

/// A stand-in climate run: `z` and `t` on the WeatherBench grid and the constant maps.
#[derive(Clone, Debug, PartialEq)]
pub struct StandIn {
    /// Z500-like geopotential (m^2/s^2).
    pub z: Field,
    /// T850-like temperature (K).
    pub t: Field,
    /// Constants on the WeatherBench grid: `orography` (m), `lsm` (1 where the mountains rise
    /// above 100 m), `lat2d` (degrees).
    pub constants: Vec<(String, Vec<f32>)>,
}

/// One random anomaly: a zonal wave packet at a latitude, its amplitude red noise.
struct Anomaly {
    m: f64,
    lat: f64,
    phase: f64,
    amplitude: f64,
}

fn season(t_days: f64) -> f64 {
    (t_days / 365.25 * std::f64::consts::TAU).cos() // 1 in early January
}

/// Geopotential equilibrium `g h_eq` at time `t_days` on the Gaussian grid.
fn equilibrium(cfg: &ClimateConfig, grid: &GaussianGrid, t_days: f64, anomalies: &[Anomaly], g: f64) -> Vec<f64> {
    let s = season(t_days);
    let (lat_n, lat_s) = (cfg.jet_latitude - cfg.jet_seasonal_shift * s, cfg.jet_latitude + cfg.jet_seasonal_shift * s);
    let (drop_n, drop_s) =
        (cfg.jet_drop * (1.0 + cfg.jet_seasonal_amplitude * s), cfg.jet_drop * (1.0 - cfg.jet_seasonal_amplitude * s));
    let lon = grid.lon_rad();
    let mut out = Vec::with_capacity(grid.len());
    for &mu in &grid.mu {
        let lat = mu.asin().to_degrees();
        let zonal = cfg.mean_depth
            - 0.5 * drop_n * (1.0 + ((lat - lat_n) / cfg.jet_width).tanh())
            - 0.5 * drop_s * (1.0 + ((-lat - lat_s) / cfg.jet_width).tanh());
        for &l in &lon {
            let noise: f64 = anomalies
                .iter()
                .map(|a| a.amplitude * (a.m * l + a.phase).cos() * (-((lat - a.lat) / 15.0).powi(2)).exp())
                .sum();
            out.push(g * (zonal + noise));
        }
    }
    out
}

fn tracer_equilibrium(cfg: &ClimateConfig, grid: &GaussianGrid, t_days: f64) -> Vec<f64> {
    let s = season(t_days);
    let mut out = Vec::with_capacity(grid.len());
    for &mu in &grid.mu {
        // mu = sin(lat): colder poles, the winter hemisphere colder still.
        let q = 288.0 - cfg.tracer_contrast * mu * mu - 12.0 * mu * s;
        out.extend(std::iter::repeat_n(q, grid.n_lon()));
    }
    out
}

/// Surface height (m) of two Gaussian mountains (an "Asian" one at 35N 90E and an "American"
/// one at 45N 250E) on the Gaussian grid.
fn mountains(cfg: &ClimateConfig, grid: &GaussianGrid) -> Vec<f64> {
    let lon = grid.lon_rad();
    let peaks = [(35f64.to_radians(), 90f64.to_radians(), 1.0), (45f64.to_radians(), 250f64.to_radians(), 0.6)];
    let mut out = Vec::with_capacity(grid.len());
    for &mu in &grid.mu {
        let lat = mu.asin();
        for &l in &lon {
            let h: f64 = peaks
                .iter()
                .map(|&(plat, plon, scale)| {
                    // Great-circle distance in radians; e-folding 15 degrees.
                    let c = (lat.sin() * plat.sin() + lat.cos() * plat.cos() * (l - plon).cos()).clamp(-1.0, 1.0);
                    scale * (-(c.acos() / 15f64.to_radians()).powi(2)).exp()
                })
                .sum();
            out.push(cfg.mountain_height * h);
        }
    }
    out
}

/// One stored time of a run: `z` and `t` on the WeatherBench grid.
pub struct Output<'a> {
    /// The time.
    pub time: Seconds,
    /// Z500-like field `[lat, lon]`.
    pub z: &'a [f64],
    /// T850-like field `[lat, lon]`.
    pub t: &'a [f64],
}

/// Runs the stand-in climate for `spinup_days`, then `days` more, handing each stored time to
/// `on_output` (which may stop the run with an error) without keeping it: a long run needs no
/// memory for its output. Returns the constant maps. `progress` gets the fraction done.
pub fn run_streaming(
    cfg: &ClimateConfig,
    start: Seconds,
    spinup_days: f64,
    days: f64,
    mut progress: impl FnMut(f64),
    mut on_output: impl FnMut(Output) -> Result<()>,
) -> Result<Vec<(String, Vec<f32>)>> {
    cfg.check()?;
    let mut params = ModelParams::new(cfg.truncation, cfg.n_lat, cfg.dt);
    params.drag = 1.0 / (cfg.drag_days * 86_400.0);
    params.hyperdiffusion = Some(Hyperdiffusion { order: 2, tau: cfg.hyperdiffusion_hours * 3600.0 });
    let g = params.planet.gravity;
    let mut model = ShallowWater::new(params)?;
    let grid = model.grid().clone();
    let hs = mountains(cfg, &grid);
    let mut rng = pbdl_core::seed::rng(cfg.seed);
    let mut anomalies: Vec<Anomaly> = (0..24)
        .map(|k| Anomaly {
            m: (1 + k % 8) as f64,
            lat: if k % 2 == 0 { 1.0 } else { -1.0 } * rng.random_range(25.0..65.0),
            phase: rng.random_range(0.0..std::f64::consts::TAU),
            amplitude: 0.0,
        })
        .collect();
    let day0 = start as f64 / 86_400.0 - spinup_days;
    let phi_eq = equilibrium(cfg, &grid, day0, &anomalies, g);
    // Start at rest on the equilibrium minus the mountains (the free surface flat).
    let phi0: Vec<f64> = phi_eq.iter().zip(&hs).map(|(p, h)| p - g * h).collect();
    let zeros = vec![0.0; grid.len()];
    model.set_state_from_winds(&zeros, &zeros, &phi0)?;
    model.set_orography(&hs.iter().map(|h| g * h).collect::<Vec<_>>())?;
    model.set_tracer(&tracer_equilibrium(cfg, &grid, day0))?;
    let steps_per_output = (cfg.output_hours as f64 * 3600.0 / cfg.dt).round() as usize;
    let spinup_steps = (spinup_days * 86_400.0 / cfg.dt).round() as usize;
    let n_out = (days * 24.0 / cfg.output_hours as f64).round() as usize;
    let total = spinup_steps + n_out * steps_per_output;
    // Red noise: a(t + dt) = r a(t) + sqrt(1 - r^2) sigma xi, updated every 6 hours.
    let update_every = (6.0 * 3600.0 / cfg.dt).round().max(1.0) as usize;
    let r = (-(update_every as f64 * cfg.dt) / (cfg.noise_days * 86_400.0)).exp();
    let sigma = cfg.noise_height / (anomalies.len() as f64 / 4.0).sqrt();
    for step in 0..total {
        if step % update_every == 0 {
            for a in &mut anomalies {
                let xi: f64 = StandardNormal.sample(&mut rng);
                a.amplitude = r * a.amplitude + (1.0 - r * r).sqrt() * sigma * xi;
            }
            let day = day0 + step as f64 * cfg.dt / 86_400.0;
            model.set_relaxation(&equilibrium(cfg, &grid, day, &anomalies, g), cfg.relaxation_days * 86_400.0)?;
            model.set_tracer_relaxation(&tracer_equilibrium(cfg, &grid, day), cfg.tracer_days * 86_400.0)?;
            progress(step as f64 / total as f64);
        }
        if step >= spinup_steps && (step - spinup_steps) % steps_per_output == 0 {
            let free_surface: Vec<f64> = model.geopotential().iter().zip(&hs).map(|(p, h)| p + g * h).collect();
            let (zw, tw) = (to_weatherbench(&grid, &free_surface)?, to_weatherbench(&grid, &model.tracer())?);
            if zw.iter().chain(&tw).any(|x| !x.is_finite()) {
                return Err(Error::Model(format!(
                    "the stand-in climate blew up after {:.1} days",
                    step as f64 * cfg.dt / 86_400.0
                )));
            }
            let time = start + ((step - spinup_steps) as f64 * cfg.dt).round() as Seconds;
            on_output(Output { time, z: &zw, t: &tw })?;
        }
        model.step();
    }
    progress(1.0);
    let wb = LatLonGrid::weatherbench(cfg.n_lat);
    let hs_wb = to_weatherbench(&grid, &hs)?;
    let lat2d: Vec<f32> = wb.lat.iter().flat_map(|&l| std::iter::repeat_n(l as f32, wb.n_lon())).collect();
    Ok(vec![
        ("orography".to_string(), hs_wb.iter().map(|&h| h as f32).collect()),
        ("lsm".to_string(), hs_wb.iter().map(|&h| if h > 100.0 { 1.0 } else { 0.0 }).collect()),
        ("lat2d".to_string(), lat2d),
    ])
}

/// Runs the stand-in climate for `spinup_days`, then stores `days` of output starting at
/// `start` (seconds since 1970). `progress` is called with the fraction done.
pub fn run(
    cfg: &ClimateConfig,
    start: Seconds,
    spinup_days: f64,
    days: f64,
    progress: impl FnMut(f64),
) -> Result<StandIn> {
    let n_out = (days * 24.0 / cfg.output_hours.max(1) as f64).round() as usize;
    let wb = LatLonGrid::weatherbench(cfg.n_lat);
    let plane = wb.n_lat() * wb.n_lon();
    let (mut z, mut t, mut times) =
        (Vec::with_capacity(n_out * plane), Vec::with_capacity(n_out * plane), Vec::with_capacity(n_out));
    let constants = run_streaming(cfg, start, spinup_days, days, progress, |o| {
        z.extend(o.z.iter().map(|&x| x as f32));
        t.extend(o.t.iter().map(|&x| x as f32));
        times.push(o.time);
        Ok(())
    })?;
    let z = Field::new("z", Some(times.clone()), wb.clone(), Values::F32(z))?;
    let t = Field::new("t", Some(times), wb, Values::F32(t))?;
    Ok(StandIn { z, t, constants })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stand_in_climate_is_finite_plausible_and_unsteady() {
        // 20 days of spin-up and 30 stored days from 2017-01-01.
        let run = run(&ClimateConfig::default(), 1_483_228_800, 20.0, 30.0, |_| {}).unwrap();
        assert_eq!(run.z.n_time(), 120);
        let (z, t) = (run.z.values.to_f64(), run.t.values.to_f64());
        let range = |v: &[f64]| v.iter().fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
        let (zmin, zmax) = range(&z);
        let (tmin, tmax) = range(&t);
        assert!(zmin > 3.0e4 && zmax < 6.5e4, "z in {zmin}..{zmax}");
        assert!(tmin > 200.0 && tmax < 300.0, "t in {tmin}..{tmax}");
        // Day-to-day change of z in the northern mid-latitudes (rows 20..28): weather, not a
        // steady state.
        let plane = 32 * 64;
        let mut change = 0.0;
        for d in 1..30 {
            for q in 20 * 64..28 * 64 {
                change += (z[4 * d * plane + q] - z[4 * (d - 1) * plane + q]).powi(2);
            }
        }
        let rms = (change / (29.0 * 8.0 * 64.0)).sqrt();
        assert!(rms > 50.0, "day-to-day rms change of z {rms} m^2/s^2");
        assert_eq!(run.constants.len(), 3);
    }
}
