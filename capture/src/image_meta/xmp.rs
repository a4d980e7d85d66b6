//! XMP packets: found in a JPEG's APP1 segment, parsed as XML with namespaces resolved, every
//! property (an attribute of an `rdf:Description`, or a simple element) kept as
//! `namespace-uri#Name` → value; DJI's fields read from them.

use std::collections::BTreeMap;

use quick_xml::events::Event;
use quick_xml::name::ResolveResult;
use quick_xml::reader::NsReader;

use super::{Attitude, DJI_NS, GeoPosition, ImageMeta};

const XMP_APP1: &[u8] = b"http://ns.adobe.com/xap/1.0/\0";
/// Namespaces of XMP's structure, not properties.
const STRUCTURE: [&str; 3] = [
    "http://www.w3.org/1999/02/22-rdf-syntax-ns#",
    "adobe:ns:meta/",
    "http://www.w3.org/2000/xmlns/",
];

/// The XMP packet of a JPEG (`None` for a JPEG without one, or a file that is not a JPEG).
pub fn packet_in_jpeg(bytes: &[u8]) -> Result<Option<&str>, String> {
    if !bytes.starts_with(&[0xff, 0xd8]) {
        return Ok(None);
    }
    for seg in crate::jpeg_segments::segments(bytes)? {
        if seg.marker == 0xe1
            && let Some(packet) = seg.payload.strip_prefix(XMP_APP1)
        {
            return std::str::from_utf8(packet)
                .map(Some)
                .map_err(|e| format!("the XMP packet is not UTF-8: {e}"));
        }
    }
    Ok(None)
}

/// Every property of the packet `text`, `namespace-uri#Name` → value.
pub fn properties(text: &str) -> Result<BTreeMap<String, String>, String> {
    let mut reader = NsReader::from_str(text);
    let mut props = BTreeMap::new();
    // the open elements: the property key of each that is a property (not structure)
    let mut open: Vec<Option<String>> = Vec::new();
    let key = |ns: &ResolveResult, local: &[u8]| -> Option<String> {
        match ns {
            ResolveResult::Bound(ns) => {
                let ns = String::from_utf8_lossy(ns.as_ref()).into_owned();
                (!STRUCTURE.contains(&ns.as_str()))
                    .then(|| format!("{ns}#{}", String::from_utf8_lossy(local)))
            }
            _ => None,
        }
    };
    loop {
        let (ns, event) = reader.read_resolved_event().map_err(|e| e.to_string())?;
        // the element's own key, owned: `ns` borrows the reader
        let element = match &event {
            Event::Start(e) => key(&ns, e.local_name().as_ref()),
            _ => None,
        };
        match event {
            Event::Start(ref e) | Event::Empty(ref e) => {
                for a in e.attributes() {
                    let a = a.map_err(|e| e.to_string())?;
                    let (ans, local) = reader.resolve_attribute(a.key);
                    if let Some(k) = key(&ans, local.as_ref()) {
                        let v = a.unescape_value().map_err(|e| e.to_string())?;
                        props.insert(k, v.trim().to_string());
                    }
                }
                if matches!(event, Event::Start(_)) {
                    open.push(element);
                }
            }
            Event::Text(t) => {
                if let Some(Some(k)) = open.last() {
                    let v = t.unescape().map_err(|e| e.to_string())?;
                    let v = v.trim();
                    if !v.is_empty() {
                        props.insert(k.clone(), v.to_string());
                    }
                }
            }
            Event::End(_) => {
                open.pop();
            }
            Event::Eof => {
                if !open.is_empty() {
                    return Err(format!(
                        "the packet ends with {} element(s) still open (truncated)",
                        open.len()
                    ));
                }
                break;
            }
            _ => {}
        }
    }
    Ok(props)
}

/// DJI's position, altitudes and angles from `props` into `meta` (an unreadable number is an
/// error naming it; a field that is absent leaves its value `None`).
pub fn apply_dji(props: &BTreeMap<String, String>, meta: &mut ImageMeta) -> Result<(), String> {
    let num = |name: &str| -> Result<Option<f64>, String> {
        match props.get(&format!("{DJI_NS}#{name}")) {
            None => Ok(None),
            Some(v) => v
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .map(Some)
                .ok_or_else(|| format!("drone-dji:{name} is {v:?}, not a number")),
        }
    };
    // some DJI firmwares spell it "Longtitude"
    let lon = match num("GpsLongitude")? {
        Some(x) => Some(x),
        None => num("GpsLongtitude")?,
    };
    if let (Some(latitude_deg), Some(longitude_deg)) = (num("GpsLatitude")?, lon) {
        meta.gps_xmp = Some(GeoPosition {
            latitude_deg,
            longitude_deg,
            altitude_m: num("AbsoluteAltitude")?,
        });
    }
    meta.relative_altitude_m = num("RelativeAltitude")?;
    let attitude = |prefix: &str| -> Result<Option<Attitude>, String> {
        Ok(
            match (
                num(&format!("{prefix}YawDegree"))?,
                num(&format!("{prefix}PitchDegree"))?,
                num(&format!("{prefix}RollDegree"))?,
            ) {
                (Some(yaw_deg), Some(pitch_deg), Some(roll_deg)) => Some(Attitude {
                    yaw_deg,
                    pitch_deg,
                    roll_deg,
                }),
                _ => None,
            },
        )
    };
    meta.gimbal = attitude("Gimbal")?;
    meta.flight = attitude("Flight")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// Properties are found by namespace, whatever the prefix, as attributes or as simple
    /// elements; structure (rdf, x) is not a property; a bad number is named.
    #[test]
    fn properties_resolve_namespaces_and_dji_fields_read() {
        let packet = r#"<x:xmpmeta xmlns:x="adobe:ns:meta/">
 <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
  <rdf:Description rdf:about="" xmlns:d="http://www.dji.com/drone-dji/1.0/"
    d:GpsLatitude="+47.1" d:GpsLongtitude="-8.5" d:RelativeAltitude="+12.30"
    d:GimbalYawDegree="-90.0" d:GimbalPitchDegree="-45.5" d:GimbalRollDegree="0.0">
   <d:AbsoluteAltitude>451.25</d:AbsoluteAltitude>
  </rdf:Description>
 </rdf:RDF>
</x:xmpmeta>"#;
        let props = properties(packet).unwrap();
        assert_eq!(
            props
                .get(&format!("{DJI_NS}#AbsoluteAltitude"))
                .map(String::as_str),
            Some("451.25")
        );
        assert!(
            props.keys().all(|k| k.starts_with(DJI_NS)),
            "only DJI properties: {props:?}"
        );
        let mut meta = ImageMeta::default();
        apply_dji(&props, &mut meta).unwrap();
        let gps = meta.gps_xmp.unwrap();
        assert_eq!((gps.latitude_deg, gps.longitude_deg), (47.1, -8.5));
        assert_eq!(gps.altitude_m, Some(451.25));
        assert_eq!(meta.relative_altitude_m, Some(12.3));
        assert_eq!(meta.gimbal.unwrap().pitch_deg, -45.5);
        assert_eq!(meta.flight, None, "no flight angles in the packet");

        let bad = packet.replace("+12.30", "twelve");
        let mut meta = ImageMeta::default();
        let e = apply_dji(&properties(&bad).unwrap(), &mut meta).unwrap_err();
        assert!(
            e.contains("RelativeAltitude") && e.contains("twelve"),
            "{e}"
        );
        assert!(properties("<a></b>").is_err(), "mismatched tags");
        let truncated = properties(&packet[..packet.find("</rdf:Description>").unwrap()]);
        assert!(
            truncated.as_ref().is_err_and(|e| e.contains("truncated")),
            "a truncated packet: {truncated:?}"
        );
    }
}
