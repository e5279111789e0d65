use hinge_core::HingeEnergy;

#[derive(HingeEnergy)]
#[psi(k * (theta - theta_bar).sinn() + theta.log(2.0))]
pub struct Bad {
    pub k: f64,
}

fn main() {}
