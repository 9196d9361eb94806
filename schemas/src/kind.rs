//! The representation kinds, each with one name: the represent node's output id, the `kind` key
//! of a [`crate::Representation`], and the graph's input id downstream.

use std::fmt;
use std::str::FromStr;

/// What a representation tensor holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum RepresentationKind {
    /// TFP: firing rate per tick over the window, 1 channel.
    Tfp,
    /// The inter-spike interval at the reference plane in ticks, and its validity (1/0): 2
    /// channels.
    Isi,
    /// NeuSpike-Net's spike representation: 1/ISI, then raw planes; N channels.
    SpikeRepr,
    /// NeuSpike-Net's event integration (Eq. 8), one channel per instant.
    EventIntegration,
    /// TFSTP's firing rate per tick from short-term plasticity synapses, 1 channel.
    Stp,
    /// E2VID's voxel grid of the window's events: B bins, linear in time.
    VoxelGrid,
    /// Event stacking: the signed event count per pixel in each of B equal time bins.
    EventStack,
    /// The time surface at the reference instant: ON and OFF channels, `exp(-age / tau)`.
    TimeSurface,
}

impl RepresentationKind {
    /// Every kind, in the order their names are listed in errors.
    pub const ALL: [RepresentationKind; 8] = [
        RepresentationKind::Tfp,
        RepresentationKind::Isi,
        RepresentationKind::SpikeRepr,
        RepresentationKind::EventIntegration,
        RepresentationKind::Stp,
        RepresentationKind::VoxelGrid,
        RepresentationKind::EventStack,
        RepresentationKind::TimeSurface,
    ];

    /// The kind's one name.
    pub const fn name(self) -> &'static str {
        match self {
            RepresentationKind::Tfp => "tfp",
            RepresentationKind::Isi => "isi",
            RepresentationKind::SpikeRepr => "spike_repr",
            RepresentationKind::EventIntegration => "event_integration",
            RepresentationKind::Stp => "stp",
            RepresentationKind::VoxelGrid => "voxel_grid",
            RepresentationKind::EventStack => "event_stack",
            RepresentationKind::TimeSurface => "time_surface",
        }
    }

    /// The accepted names, comma-separated, for errors.
    pub fn accepted() -> String {
        Self::ALL.map(Self::name).join(", ")
    }
}

impl fmt::Display for RepresentationKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is not a representation kind.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("`{value}` is not a representation kind (one of {accepted})", accepted = RepresentationKind::accepted())]
pub struct UnknownKind {
    /// The name given.
    pub value: String,
}

impl FromStr for RepresentationKind {
    type Err = UnknownKind;

    /// The exact name; anything else is an error naming the value and the accepted names.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| UnknownKind {
                value: s.to_string(),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_kind_parses_back_from_its_name_and_nothing_else_does() {
        for k in RepresentationKind::ALL {
            assert_eq!(k.name().parse::<RepresentationKind>(), Ok(k));
        }
        let e = "spike-repr".parse::<RepresentationKind>().unwrap_err();
        assert!(e.to_string().contains("`spike-repr`") && e.to_string().contains("spike_repr"));
    }
}
