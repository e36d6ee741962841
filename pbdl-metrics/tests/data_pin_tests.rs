//! Pins the exact values of the metric data generator (every kind, 2 sequences at 32^2), so that changes to how it is scheduled over threads cannot change the data.
//! Recorded before the generator ran its sequences in parallel / in a serial scope.

use pbdl_metrics::train::data::{generate, DataConfig, Kind};

/// FNV-1a over the f32 bits of every frame of every sequence.
fn fingerprint(kind: Kind, count: usize, n: usize) -> u64 {
    let seqs = generate(kind, count, &DataConfig { resolution: n, seed: 3 }).unwrap();
    seqs.iter()
        .flat_map(|s| s.frames.flatten_all().unwrap().to_vec1::<f32>().unwrap())
        .fold(0xcbf2_9ce4_8422_2325u64, |h, v| (h ^ u64::from(v.to_bits())).wrapping_mul(0x0100_0000_01b3))
}

#[test]
fn generated_data_is_pinned() {
    let got: Vec<u64> = Kind::ALL.iter().map(|&k| fingerprint(k, 2, 32)).collect();
    assert_eq!(got, [0x620e_d104_c27c_c556, 0x5ff6_f288_160d_6012, 0xdd05_73c3_9be7_294b, 0xd4da_c18c_bdc7_4fab]);
}
