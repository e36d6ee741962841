//! CF time coordinates ("hours since 1979-01-01") to seconds since 1970-01-01 00:00 UTC.
//!
//! Times are kept as `i64` seconds so that a forecast's valid time (`init + lead`) and the
//! truth's time compare exactly, as xarray's inner join on `datetime64` values does. Only the
//! standard (Gregorian) calendar is accepted; WeatherBench and ERA5 use it.

/// A time as seconds since 1970-01-01 00:00:00 UTC.
pub type Seconds = i64;

/// Seconds per hour.
pub const HOUR: Seconds = 3600;

/// Days from 1970-01-01 to the given proleptic Gregorian date (Howard Hinnant's algorithm).
pub fn days_from_civil(year: i64, month: u32, day: u32) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let m = month as i64;
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + day as i64 - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// The (year, month, day) of a day count from 1970-01-01 (inverse of [`days_from_civil`]).
pub fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    (year, month, day)
}

/// Day of year (1-based) and hour of day of a time, as pandas' `dayofyear` and `hour`.
pub fn day_of_year_and_hour(t: Seconds) -> (u32, u32) {
    let days = t.div_euclid(86_400);
    let hour = (t.rem_euclid(86_400) / 3600) as u32;
    let (year, _, _) = civil_from_days(days);
    let doy = (days - days_from_civil(year, 1, 1) + 1) as u32;
    (doy, hour)
}

/// The length of a unit word in seconds: `seconds`, `minutes`, `hours`, `days` and their
/// singular and abbreviated forms.
pub fn unit_seconds(unit: &str) -> Option<f64> {
    match unit.trim().to_ascii_lowercase().as_str() {
        "seconds" | "second" | "secs" | "sec" | "s" => Some(1.0),
        "minutes" | "minute" | "mins" | "min" => Some(60.0),
        "hours" | "hour" | "hrs" | "hr" | "h" => Some(3600.0),
        "days" | "day" | "d" => Some(86_400.0),
        _ => None,
    }
}

/// A parsed `"<unit> since <date>[ <time>][ UTC]"` time encoding.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeEncoding {
    /// Seconds per unit.
    pub unit: f64,
    /// The reference time.
    pub epoch: Seconds,
}

impl TimeEncoding {
    /// Parses CF units such as `hours since 1900-01-01 00:00:00.0` or `days since 2017-01-01T06:00`.
    pub fn parse(units: &str) -> Option<Self> {
        let (unit, rest) = units.split_once(" since ")?;
        let unit = unit_seconds(unit)?;
        let rest = rest.trim().trim_end_matches("UTC").trim_end_matches('Z').trim();
        let (date, clock) = match rest.split_once(['T', ' ']) {
            Some((d, c)) => (d, c.trim()),
            None => (rest, ""),
        };
        let mut parts = date.split('-');
        let year: i64 = parts.next()?.parse().ok()?;
        let month: u32 = parts.next().unwrap_or("1").parse().ok()?;
        let day: u32 = parts.next().unwrap_or("1").parse().ok()?;
        if !(1..=12).contains(&month) || !(1..=31).contains(&day) {
            return None;
        }
        let mut seconds = 0.0;
        if !clock.is_empty() {
            let clock = clock.split(['+']).next().unwrap_or(clock);
            let mut c = clock.split(':');
            let h: f64 = c.next()?.parse().ok()?;
            let m: f64 = c.next().unwrap_or("0").parse().ok()?;
            let s: f64 = c.next().unwrap_or("0").parse().ok()?;
            seconds = h * 3600.0 + m * 60.0 + s;
        }
        let epoch = days_from_civil(year, month, day) * 86_400 + seconds.round() as i64;
        Some(Self { unit, epoch })
    }

    /// The time of an encoded value, rounded to the second.
    pub fn decode(&self, value: f64) -> Seconds {
        self.epoch + (value * self.unit).round() as i64
    }
}

/// Calendars in which the standard encoding above is exact for WeatherBench's dates.
pub fn is_gregorian(calendar: &str) -> bool {
    matches!(calendar.trim().to_ascii_lowercase().as_str(), "standard" | "gregorian" | "proleptic_gregorian")
}

/// `YYYY-MM-DDTHH:MM:SS` of a time, for messages and file attributes.
pub fn format_time(t: Seconds) -> String {
    let days = t.div_euclid(86_400);
    let s = t.rem_euclid(86_400);
    let (y, m, d) = civil_from_days(days);
    format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}", s / 3600, (s / 60) % 60, s % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn civil_day_counts_round_trip_and_match_known_dates() {
        assert_eq!(days_from_civil(1970, 1, 1), 0);
        // 2017-01-01 is 17167 days after the Unix epoch (numpy: np.datetime64('2017-01-01').astype(int)).
        assert_eq!(days_from_civil(2017, 1, 1), 17_167);
        assert_eq!(days_from_civil(1900, 1, 1), -25_567);
        for d in [-100_000, -25_567, 0, 17_167, 18_321, 50_000] {
            let (y, m, dd) = civil_from_days(d);
            assert_eq!(days_from_civil(y, m, dd), d);
        }
    }

    #[test]
    fn cf_units_parse_as_xarray_decodes_them() {
        let e = TimeEncoding::parse("hours since 1900-01-01 00:00:00.0").unwrap();
        // 1017072 hours after 1900 is 2016-01-11 00:00 (1017072 / 24 = 42378 days).
        assert_eq!(format_time(e.decode(1_017_072.0)), "2016-01-11T00:00:00");
        let e = TimeEncoding::parse("days since 2017-01-01T06:00:00").unwrap();
        assert_eq!(format_time(e.decode(0.25)), "2017-01-01T12:00:00");
        assert!(TimeEncoding::parse("fortnights since 2017-01-01").is_none());
        assert_eq!(day_of_year_and_hour(days_from_civil(2016, 12, 31) * 86_400 + 7 * 3600), (366, 7));
    }
}
