//! The settings and inputs a message may point the user to, named as the
//! library knows them. The library never spells a front end's flag: it
//! writes a [`Knob`], and the front end that runs it (the command line,
//! the Python bindings) says how its users spell that knob
//! ([`spell_with`]). Without a front end a knob is its plain name
//! (`max_range`, `classes`), which is also the Python keyword where one
//! exists.

use std::sync::OnceLock;

/// A setting or input of the library's jobs that a message can name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Knob {
    /// A class table mapping a user's label ids.
    Classes,
    /// The crop range: points farther than this from their sensor are left out.
    MaxRange,
    /// Moving objects kept instead of dropped.
    KeepMoving,
    /// The cap on an image's (or a network input's) pixels.
    MaxPixels,
    /// A recording cut short is an error instead of a warning.
    Strict,
    /// The camera images' size.
    ImageSize,
    /// A frame range or count.
    Frames,
    /// A segmentation network (ONNX).
    Model,
    /// A folder of camera images.
    Images,
    /// A folder of segmentation images.
    Seg,
    /// A data folder (a SemanticKITTI sequence, a recording).
    Data,
    /// An output folder.
    Out,
    /// An output file.
    Output,
    /// A folder of images to check against.
    CheckDir,
    /// An earlier output replaced.
    Force,
    /// A robot team without a prior.
    NoPrior,
    /// A false match injected between two robots.
    InjectFalseMatch,
    /// The robots run on emulated boards.
    OnBoard,
    /// The first robot's board.
    BoardA,
    /// The second robot's board.
    BoardB,
    /// An input file given by position.
    File,
    /// Which channel of a probability map is the network's void.
    VoidChannel,
    /// The camera projection scaled to the segmentation's size.
    ScaleToImages,
    /// A DDS domain id.
    Domain,
    /// Scans a second where a source has no timestamps.
    Rate,
    /// Times a recording's rate.
    Speed,
    /// Readers each topic waits for before the first message.
    WaitReaders,
}

impl Knob {
    /// Every knob (for a front end's table and its tests).
    pub const ALL: [Knob; 27] = [
        Knob::Classes,
        Knob::MaxRange,
        Knob::KeepMoving,
        Knob::MaxPixels,
        Knob::Strict,
        Knob::ImageSize,
        Knob::Frames,
        Knob::Model,
        Knob::Images,
        Knob::Seg,
        Knob::Data,
        Knob::Out,
        Knob::Output,
        Knob::CheckDir,
        Knob::Force,
        Knob::NoPrior,
        Knob::InjectFalseMatch,
        Knob::OnBoard,
        Knob::BoardA,
        Knob::BoardB,
        Knob::File,
        Knob::VoidChannel,
        Knob::ScaleToImages,
        Knob::Domain,
        Knob::Rate,
        Knob::Speed,
        Knob::WaitReaders,
    ];

    /// The knob's plain name: the library's (and the Python keyword's).
    pub fn plain(self) -> &'static str {
        match self {
            Knob::Classes => "classes",
            Knob::MaxRange => "max_range",
            Knob::KeepMoving => "keep_moving",
            Knob::MaxPixels => "max_pixels",
            Knob::Strict => "strict",
            Knob::ImageSize => "image_size",
            Knob::Frames => "frames",
            Knob::Model => "model",
            Knob::Images => "images",
            Knob::Seg => "seg",
            Knob::Data => "data",
            Knob::Out => "out",
            Knob::Output => "output",
            Knob::CheckDir => "check_dir",
            Knob::Force => "force",
            Knob::NoPrior => "no_prior",
            Knob::InjectFalseMatch => "inject_false_match",
            Knob::OnBoard => "on_board",
            Knob::BoardA => "board_a",
            Knob::BoardB => "board_b",
            Knob::File => "file",
            Knob::VoidChannel => "void_channel",
            Knob::ScaleToImages => "scale_to_images",
            Knob::Domain => "domain",
            Knob::Rate => "rate",
            Knob::Speed => "speed",
            Knob::WaitReaders => "wait_readers",
        }
    }

    /// The knob as the running front end spells it (its plain name when
    /// none said).
    pub fn name(self) -> &'static str {
        SPELLING.get().map_or_else(|| self.plain(), |spell| spell(self))
    }
}

impl std::fmt::Display for Knob {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

static SPELLING: OnceLock<fn(Knob) -> &'static str> = OnceLock::new();

/// The front end says, once, how its users spell each knob (the command
/// line: its flags). A second call is ignored: one process, one front end.
pub fn spell_with(spell: fn(Knob) -> &'static str) {
    let _ = SPELLING.set(spell);
}
