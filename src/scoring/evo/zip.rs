//! `--save_results FILE.zip` in evo's own format, so that `evo_res` and
//! `evo.tools.file_interface.load_res_file` read vinebench's results: an uncompressed ZIP
//! of `info.json`, `stats.json` and one `.npy` (format 1.0, little-endian float64) per
//! array, in evo's order.

use super::EvoResult;

/// A `.npy` (version 1.0) of a float64 array of `shape`.
fn npy(values: &[f64], shape: &str) -> Vec<u8> {
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {shape}, }}");
    // Magic (6) + version (2) + length (2) + header, padded with spaces and ended by a
    // newline to a multiple of 64.
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((header.len() as u16).to_le_bytes());
    out.extend(header.as_bytes());
    for v in values {
        out.extend(v.to_le_bytes());
    }
    out
}

/// The members of `r`'s zip, in evo's order.
fn members(r: &EvoResult) -> Result<Vec<(String, Vec<u8>)>, serde_json::Error> {
    let mut m = vec![
        ("info.json".to_string(), serde_json::to_vec(&r.info)?),
        ("stats.json".to_string(), serde_json::to_vec(&r.stats)?),
    ];
    let a = &r.np_arrays;
    let mut vector = |name: &str, v: &[f64]| {
        m.push((format!("{name}.npy"), npy(v, &format!("({},)", v.len()))));
    };
    vector("error_array", &a.error_array);
    for (name, v) in [
        ("seconds_from_start", &a.seconds_from_start),
        ("timestamps", &a.timestamps),
        ("distances_from_start", &a.distances_from_start),
        ("distances", &a.distances),
    ] {
        if let Some(v) = v {
            vector(name, v);
        }
    }
    if let Some(t) = &a.alignment_transformation_sim3 {
        let flat: Vec<f64> = t.iter().flatten().copied().collect();
        m.push((
            "alignment_transformation_sim3.npy".into(),
            npy(&flat, "(4, 4)"),
        ));
    }
    Ok(m)
}

/// The bytes of an uncompressed ZIP holding `r` as evo saves it.
pub fn zip(r: &EvoResult) -> Result<Vec<u8>, serde_json::Error> {
    let mut out = Vec::new();
    let mut central = Vec::new();
    let files = members(r)?;
    for (name, data) in &files {
        let crc = crc32fast::hash(data);
        let offset = out.len() as u32;
        let common = |v: &mut Vec<u8>| {
            v.extend(20u16.to_le_bytes()); // version needed: 2.0
            v.extend(0u16.to_le_bytes()); // flags
            v.extend(0u16.to_le_bytes()); // stored
            v.extend(0u16.to_le_bytes()); // time
            v.extend(0x21u16.to_le_bytes()); // date: 1980-01-01
            v.extend(crc.to_le_bytes());
            v.extend((data.len() as u32).to_le_bytes());
            v.extend((data.len() as u32).to_le_bytes());
            v.extend((name.len() as u16).to_le_bytes());
            v.extend(0u16.to_le_bytes()); // extra
        };
        out.extend(0x0403_4b50u32.to_le_bytes());
        common(&mut out);
        out.extend(name.as_bytes());
        out.extend(data);
        central.extend(0x0201_4b50u32.to_le_bytes());
        central.extend(20u16.to_le_bytes()); // made by
        common(&mut central);
        central.extend(0u16.to_le_bytes()); // comment
        central.extend(0u16.to_le_bytes()); // disk
        central.extend(0u16.to_le_bytes()); // internal attributes
        central.extend(0u32.to_le_bytes()); // external attributes
        central.extend(offset.to_le_bytes());
        central.extend(name.as_bytes());
    }
    let (cd_offset, cd_len) = (out.len() as u32, central.len() as u32);
    out.extend(central);
    out.extend(0x0605_4b50u32.to_le_bytes());
    out.extend(0u16.to_le_bytes());
    out.extend(0u16.to_le_bytes());
    out.extend((files.len() as u16).to_le_bytes());
    out.extend((files.len() as u16).to_le_bytes());
    out.extend(cd_len.to_le_bytes());
    out.extend(cd_offset.to_le_bytes());
    out.extend(0u16.to_le_bytes());
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_headers_are_padded_to_64_bytes() {
        for n in [0, 1, 12, 12345] {
            let b = npy(&vec![1.5; n], &format!("({n},)"));
            let hlen = u16::from_le_bytes([b[8], b[9]]) as usize;
            assert_eq!((10 + hlen) % 64, 0);
            assert_eq!(b[10 + hlen - 1], b'\n');
            assert_eq!(b.len(), 10 + hlen + 8 * n);
        }
    }
}
