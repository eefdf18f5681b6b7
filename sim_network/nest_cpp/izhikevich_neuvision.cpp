/*
 *  izhikevich_neuvision.cpp
 *
 *  Part of NeuVision (GPL-3.0-or-later), built against NEST (GPL-2.0-or-later).
 *  What the model is: izhikevich_neuvision.h.
 */

#include "izhikevich_neuvision.h"

#include <cmath>
#include <limits>
#include <string>

#include "dict_util.h"
#include "event_delivery_manager_impl.h"
#include "exceptions.h"
#include "kernel_manager.h"
#include "nest_impl.h"
#include "universal_data_logger_impl.h"

nest::RecordablesMap< neuvision::izhikevich_neuvision > neuvision::izhikevich_neuvision::recordablesMap_;

namespace
{
// sim_network/kernels.py's noise: xoshiro128++ (Blackman & Vigna 2018) and an Irwin-Hall(4)
// variate from the four bytes of one draw, scaled to mean 0 and s.d. 1 in single precision.
// The multiply-adds are fused, as numba (fastmath "contract") compiles them.
const float IH_SCALE = static_cast< float >( std::sqrt( 3.0 ) / 256.0 / std::sqrt( 1.0 - std::pow( 2.0, -16 ) ) );
const float IH_SHIFT =
  static_cast< float >( ( 2.0 / 256.0 - 2.0 ) * std::sqrt( 3.0 ) / std::sqrt( 1.0 - std::pow( 2.0, -16 ) ) );

inline uint32_t
rotl( uint32_t x, int k )
{
  return ( x << k ) | ( x >> ( 32 - k ) );
}

inline uint32_t
xoshiro128pp( uint32_t* s )
{
  const uint32_t result = rotl( s[ 0 ] + s[ 3 ], 7 ) + s[ 0 ];
  const uint32_t t = s[ 1 ] << 9;
  s[ 2 ] ^= s[ 0 ];
  s[ 3 ] ^= s[ 1 ];
  s[ 1 ] ^= s[ 2 ];
  s[ 0 ] ^= s[ 3 ];
  s[ 2 ] ^= t;
  s[ 3 ] = rotl( s[ 3 ], 11 );
  return result;
}

inline float
irwin_hall4( uint32_t r )
{
  const uint32_t pairs = ( r & 0x00FF00FFu ) + ( ( r >> 8 ) & 0x00FF00FFu );
  const uint32_t total = ( pairs + ( pairs >> 16 ) ) & 0x3FFu;
  return std::fmaf( static_cast< float >( static_cast< int32_t >( total ) ), IH_SCALE, IH_SHIFT );
}
}  // namespace

namespace nest
{
template <>
void
RecordablesMap< neuvision::izhikevich_neuvision >::create()
{
  insert_( names::V_m, &neuvision::izhikevich_neuvision::get_V_m_ );
  insert_( names::U_m, &neuvision::izhikevich_neuvision::get_U_m_ );
  insert_( "I_adapt", &neuvision::izhikevich_neuvision::get_I_adapt_ );
  insert_( "I_slow", &neuvision::izhikevich_neuvision::get_I_slow_ );
}
}  // namespace nest

namespace neuvision
{

void
register_izhikevich_neuvision( const std::string& name )
{
  nest::register_node_model< izhikevich_neuvision >( name );
}

izhikevich_neuvision::Parameters_::Parameters_()
  : a_( 0.02 )
  , b_( 0.2 )
  , c_( -65.0 )
  , d_( 8.0 )
  , I_e_( 0.0 )
  , V_th_( 30.0 )
  , V_min_( -std::numeric_limits< double >::max() )
  , adapt_increment_( 0.0 )
  , tau_adapt_( 25.0 )
  , slow_share_( 0.0 )
  , tau_slow_( 40.0 )
  , noise_mean_( 0.0 )
  , noise_sd_( 0.0 )
  , noise_interval_( 0 )
{
}

izhikevich_neuvision::State_::State_()
  : v_( -65.0 )
  , u_( -13.0 )  // b * v, as izhikevich
  , w_( 0.0 )
  , s_( 0.0 )
  , I_( 0.0 )
  , rng_ { 1, 0, 0, 0 }
  , noise_( 0.0f )
{
}

void
izhikevich_neuvision::Parameters_::get( Dictionary& d ) const
{
  d[ nest::names::a ] = a_;
  d[ nest::names::b ] = b_;
  d[ nest::names::c ] = c_;
  d[ nest::names::d ] = d_;
  d[ nest::names::I_e ] = I_e_;
  d[ nest::names::V_th ] = V_th_;
  d[ nest::names::V_min ] = V_min_;
  d[ "adapt_increment" ] = adapt_increment_;
  d[ "tau_adapt" ] = tau_adapt_;
  d[ "slow_share" ] = slow_share_;
  d[ "tau_slow" ] = tau_slow_;
  d[ "noise_mean" ] = noise_mean_;
  d[ "noise_sd" ] = noise_sd_;
  d[ "noise_interval" ] = noise_interval_;
}

void
izhikevich_neuvision::Parameters_::set( const Dictionary& d, nest::Node* node )
{
  nest::update_value_param( d, nest::names::a, a_, node );
  nest::update_value_param( d, nest::names::b, b_, node );
  nest::update_value_param( d, nest::names::c, c_, node );
  nest::update_value_param( d, nest::names::d, d_, node );
  nest::update_value_param( d, nest::names::I_e, I_e_, node );
  nest::update_value_param( d, nest::names::V_th, V_th_, node );
  nest::update_value_param( d, nest::names::V_min, V_min_, node );
  nest::update_value_param( d, "adapt_increment", adapt_increment_, node );
  nest::update_value_param( d, "tau_adapt", tau_adapt_, node );
  nest::update_value_param( d, "slow_share", slow_share_, node );
  nest::update_value_param( d, "tau_slow", tau_slow_, node );
  nest::update_value_param( d, "noise_mean", noise_mean_, node );
  nest::update_value_param( d, "noise_sd", noise_sd_, node );
  d.update_integer_value( "noise_interval", noise_interval_ );
  if ( noise_interval_ < 0 )
  {
    throw nest::BadProperty( "noise_interval must be >= 0 steps." );
  }
  if ( not( tau_adapt_ > 0.0 ) or not( tau_slow_ > 0.0 ) )
  {
    throw nest::BadProperty( "tau_adapt and tau_slow must be > 0 ms." );
  }
  if ( not( adapt_increment_ >= 0.0 ) or not( slow_share_ >= 0.0 ) )
  {
    throw nest::BadProperty( "adapt_increment and slow_share must be >= 0." );
  }
}

void
izhikevich_neuvision::State_::get( Dictionary& d ) const
{
  d[ nest::names::V_m ] = v_;
  d[ nest::names::U_m ] = u_;
  d[ "I_adapt" ] = w_;
  d[ "I_slow" ] = s_;
  d[ "I_noise" ] = static_cast< double >( noise_ );
  for ( int j = 0; j < 4; ++j )
  {
    d[ "noise_s" + std::to_string( j ) ] = static_cast< long >( rng_[ j ] );
  }
}

void
izhikevich_neuvision::State_::set( const Dictionary& d, nest::Node* node )
{
  nest::update_value_param( d, nest::names::V_m, v_, node );
  nest::update_value_param( d, nest::names::U_m, u_, node );
  nest::update_value_param( d, "I_adapt", w_, node );
  nest::update_value_param( d, "I_slow", s_, node );
  for ( int j = 0; j < 4; ++j )
  {
    long word = rng_[ j ];
    d.update_integer_value( "noise_s" + std::to_string( j ), word );
    if ( word < 0 or word > 0xFFFFFFFFL )
    {
      throw nest::BadProperty( "noise_s0 .. noise_s3 must be 32-bit words (0 .. 2^32 - 1)." );
    }
    rng_[ j ] = static_cast< uint32_t >( word );
  }
}

void
izhikevich_neuvision::get_status( Dictionary& d ) const
{
  P_.get( d );
  S_.get( d );
  nest::ArchivingNode::get_status( d );
  d[ nest::names::recordables ] = recordablesMap_.get_list();
}

void
izhikevich_neuvision::set_status( const Dictionary& d )
{
  Parameters_ ptmp = P_;  // copies, so that a bad value changes nothing
  ptmp.set( d, this );
  State_ stmp = S_;
  stmp.set( d, this );
  nest::ArchivingNode::set_status( d );
  P_ = ptmp;
  S_ = stmp;
}

izhikevich_neuvision::Buffers_::Buffers_( izhikevich_neuvision& n )
  : logger_( n )
{
}

izhikevich_neuvision::Buffers_::Buffers_( const Buffers_&, izhikevich_neuvision& n )
  : logger_( n )
{
}

izhikevich_neuvision::izhikevich_neuvision()
  : nest::ArchivingNode()
  , P_()
  , S_()
  , B_( *this )
{
  recordablesMap_.create();
}

izhikevich_neuvision::izhikevich_neuvision( const izhikevich_neuvision& n )
  : nest::ArchivingNode( n )
  , P_( n.P_ )
  , S_( n.S_ )
  , B_( n.B_, *this )
{
}

void
izhikevich_neuvision::init_buffers_()
{
  B_.spikes_.clear();
  B_.currents_.clear();
  B_.logger_.reset();
  nest::ArchivingNode::clear_history();
}

void
izhikevich_neuvision::pre_run_hook()
{
  B_.logger_.init();
  const double h = nest::Time::get_resolution().get_ms();
  V_.adapt_decay_ = std::exp( -h / P_.tau_adapt_ );
  V_.slow_decay_ = std::exp( -h / P_.tau_slow_ );
  V_.slow_gain_ = P_.slow_share_ / P_.tau_slow_;
}

/* One step, in izhikevich's order (forward Euler from the old V and U; the jumps due now
 * added after it, so that they start the next step, as sim_network adds a jump at the start
 * of the step it is due in), with the two currents kept so that step k reads what
 * sim_network's step k reads: w decays after a spike has raised it, and s decays and takes
 * the jump that starts the next step. The noise is redrawn at the start of each window
 * (k mod noise_interval = 0), as sim_network redraws it. */
void
izhikevich_neuvision::update( nest::Time const& origin, const long from, const long to )
{
  const double h = nest::Time::get_resolution().get_ms();
  for ( long lag = from; lag < to; ++lag )
  {
    if ( P_.noise_interval_ > 0 and ( origin.get_steps() + lag ) % P_.noise_interval_ == 0 )
    {
      const float z = irwin_hall4( xoshiro128pp( S_.rng_ ) );
      S_.noise_ = std::fmaf( static_cast< float >( P_.noise_sd_ ), z, static_cast< float >( P_.noise_mean_ ) );
    }
    const double v_old = S_.v_;
    const double u_old = S_.u_;
    const double jump = B_.spikes_.get_value( lag );
    const double input = S_.I_ + P_.I_e_ - S_.w_ + S_.s_ + S_.noise_;
    S_.v_ += h * ( 0.04 * v_old * v_old + 5.0 * v_old + 140.0 - u_old + input ) + jump;
    S_.u_ += h * P_.a_ * ( P_.b_ * v_old - u_old );
    S_.v_ = ( S_.v_ < P_.V_min_ ? P_.V_min_ : S_.v_ );

    if ( S_.v_ >= P_.V_th_ )
    {
      S_.v_ = P_.c_;
      S_.u_ += P_.d_;
      S_.w_ += P_.adapt_increment_;
      set_spiketime( nest::Time::step( origin.get_steps() + lag + 1 ) );
      nest::SpikeEvent se;
      nest::kernel().event_delivery_manager.send( *this, se, lag );
    }
    S_.w_ *= V_.adapt_decay_;
    S_.s_ = S_.s_ * V_.slow_decay_ + V_.slow_gain_ * jump;

    S_.I_ = B_.currents_.get_value( lag );
    B_.logger_.record_data( origin.get_steps() + lag );
  }
}

void
izhikevich_neuvision::handle( nest::SpikeEvent& e )
{
  B_.spikes_.add_value( e.get_rel_delivery_steps( nest::kernel().simulation_manager.get_slice_origin() ),
    e.get_weight() * e.get_multiplicity() );
}

void
izhikevich_neuvision::handle( nest::CurrentEvent& e )
{
  B_.currents_.add_value( e.get_rel_delivery_steps( nest::kernel().simulation_manager.get_slice_origin() ),
    e.get_weight() * e.get_current() );
}

void
izhikevich_neuvision::handle( nest::DataLoggingRequest& e )
{
  B_.logger_.handle( e );
}

}  // namespace neuvision
