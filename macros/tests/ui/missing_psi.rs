use hinge_core::HingeEnergy;

#[derive(HingeEnergy)]
pub struct Bad {
    pub k: f64,
}

fn main() {}
